"""Names the offline RAPID check (:mod:`.rapid_syntax`) knows: reserved words, and the
instructions, functions, data types and predefined data of RAPID.

Source: the public ABB manual "Technical reference manual - RAPID Instructions,
Functions and Data types" (RobotWare 5 and 6 editions), its A-Z indexes of instructions,
functions and data types, and the predefined data it names (error numbers of ERRNO,
speeddata and zonedata, socket states, the string sets of StrFind). The lists hold the
common part, not every option's names (those of Externally Guided Motion, option 689-1,
from its application manual, are in): a valid name missing here makes the check refuse
a correct module, and is added here (with its manual section in mind), never worked
around in the module. RAPID names are case-insensitive; every set holds upper case.
"""

from __future__ import annotations


def _upper(text: str) -> frozenset[str]:
    return frozenset(word.upper() for word in text.split())


#: Reserved words (RAPID overview, "Reserved words").
RESERVED = _upper("""
ALIAS AND BACKWARD CASE CONNECT CONST DEFAULT DIV DO ELSE ELSEIF ENDFOR ENDFUNC ENDIF
ENDMODULE ENDPROC ENDRECORD ENDTEST ENDTRAP ENDWHILE ERROR EXIT FALSE FOR FROM FUNC GOTO IF
INOUT LOCAL MOD MODULE NOSTEPIN NOT NOVIEW OR PERS PROC RAISE READONLY RECORD RETRY RETURN
STEP SYSMODULE TASK TEST THEN TO TRAP TRUE TRYNEXT UNDO VAR VIEWONLY WHILE WITH XOR
""")

#: Instructions (called as statements: ``Name arg, arg \\Opt;``).
INSTRUCTIONS = _upper("""
AccSet ActUnit Add AliasIO BitClear BitSet BookErrNo Break CallByVar CancelLoad CheckProgRef
CirPathMode Clear ClearIOBuff ClearPath ClearRawBytes ClkReset ClkStart ClkStop Close CloseDir
Comment Compact ConfJ ConfL CopyFile CopyRawBytes CorrClear CorrCon CorrDiscon CorrWrite
DeactUnit Decr DropWObj EGMActJoint EGMActMove EGMActPose EGMGetId EGMMoveC EGMMoveL EGMReset
EGMRunJoint EGMRunPose EGMSetupAI EGMSetupAO EGMSetupGI EGMSetupLTAPP EGMSetupUC EGMStop EGMStreamStart
EGMStreamStop EOffsOff EOffsOn EOffsSet EraseModule ErrLog ErrRaise ErrWrite
ExitCycle GetDataVal GetSysData GetTrapData GripLoad IDelete IDisable IEnable IError Incr
IndAMove IndCMove IndDMove IndReset IndRMove InvertDO IOBusStart IOBusState IODisable IOEnable
IPers IRMQMessage ISignalAI ISignalAO ISignalDI ISignalDO ISignalGI ISignalGO ISleep ITimer
IVarValue IWatch Load LoadId MakeDir ManLoadIdProc MechUnitLoad MotionSup MoveAbsJ MoveC
MoveCDO MoveCSync MoveExtJ MoveJ MoveJDO MoveJSync MoveL MoveLDO MoveLSync MToolRotCalib
MToolTCPCalib Open OpenDir PackDNHeader PackRawBytes PathAccLim PathRecMoveBwd PathRecMoveFwd
PathRecStart PathRecStop PathResol PDispOff PDispOn PDispSet ProcerrRecovery PulseDO
RaiseToUser ReadAnyBin ReadBlock ReadCfgData ReadErrData ReadRawBytes RemoveDir RemoveFile
RenameFile Reset ResetPPMoved ResetRetryCount RestoPath Rewind RMQEmptyQueue RMQFindSlot
RMQGetMessage RMQGetMsgData RMQGetMsgHeader RMQReadWait RMQSendMessage RMQSendWait Save
SCWrite SearchC SearchExtJ SearchL SenDevice Set SetAllDataVal SetAO SetDataSearch SetDataVal
SetDO SetGO SetSysData SingArea SkipWarn SocketAccept SocketBind SocketClose SocketConnect
SocketCreate SocketListen SocketReceive SocketReceiveFrom SocketSend SocketSendTo SoftAct
SoftDeact SpeedLimAxis SpeedLimCheckPoint SpeedRefresh SpyStart SpyStop StartLoad StartMove
StartMoveRetry StepBwdPath SToolRotCalib SToolTCPCalib Stop StopMove StopMoveReset StorePath
SyncMoveOff SyncMoveOn SyncMoveResume SyncMoveSuspend SyncMoveUndo SystemStopAction
TestSignDefine TestSignReset TextTabInstall TPErase TPReadFK TPReadNum TPShow TPWrite TriggC
TriggCheckIO TriggEquip TriggInt TriggIO TriggJ TriggL TriggRampAO TriggSpeed TriggStopProc
TryInt TuneReset TuneServo UIMsgBox UIShow UnLoad UnpackRawBytes VelSet WaitAI WaitAO WaitDI
WaitDO WaitGI WaitGO WaitLoad WaitRob WaitSensor WaitSyncTask WaitTestAndSet WaitTime
WaitUntil WaitWObj WarmStart WorldAccLim Write WriteAnyBin WriteBin WriteBlock WriteCfgData
WriteRawBytes WriteStrBin WriteVar WZBoxDef WZCylDef WZDisable WZDOSet WZEnable WZFree
WZHomeJointDef WZLimJointDef WZLimSup WZSphDef
""")

#: Functions (called in expressions: ``Name(arg, arg \\Opt)``).
FUNCTIONS = _upper("""
Abs ACos AInput AOutput ArgName ASin ATan ATan2 BitAnd BitCheck BitLSh BitNeg BitOr BitRSh
BitXOr ByteToStr CalcJointT CalcRobT CalcRotAxFrameZ CalcRotAxisFrame CDate CJointT ClkRead
CorrRead Cos CPos CRobT CSpeedOverride CTime CTool CWObj DecToHex DefAccFrame DefDFrame
DefFrame Dim Distance DnumToNum EGMGetState DotProd DOutput EulerZYX EventType ExecHandler ExecLevel Exp
FileSize FileTime FSSize GetMecUnitName GetNextMechUnit GetNextSym GetServiceInfo
GetSignalOrigin GetSysInfo GetTaskName GetTime GInput GOutput HexToDec IndInpos IndSpeed
IOUnitState IsFile IsMechUnitActive IsPers IsStopMoveAct IsStopStateEvent IsSyncMoveOn
IsSysId IsVar MaxRobSpeed MirPos ModExist ModTime NonMotionMode NOrient NumToDnum NumToStr
Offs OpMode OrientZYX ORobT ParIdPosValid ParIdRobValid PathLevel PathRecValidBwd
PathRecValidFwd PFRestart PoseInv PoseMult PoseVect Pow PPMovedInManMode Present ProgMemFree
RawBytesLen ReadBin ReadDir ReadMotor ReadNum ReadStr ReadStrBin ReadVar RelTool
RemainingRetries RMQGetSlotName RobName RobOS Round RunMode Sin SocketGetStatus SocketPeek
Sqrt StrDigCalc StrDigCmp StrFind StrLen StrMap StrMatch StrMemb StrOrder StrPart StrToByte
StrToVal Tan TaskRunMec TaskRunRob TasksInSync TestAndSet TestDI TestSignRead TextGet
TextTabFreeToUse TextTabGet Trunc Type UIAlphaEntry UIClientExist UIListView UIMessageBox
UINumEntry UINumTune ValidIO ValToStr VectMagn
""")

#: Data types (atomic, record and alias types of the manual's data type index).
DATA_TYPES = _upper("""
aiotrigg bool btnres busstate buttondata byte clock confdata corrdescr datapos dionum dir
dnum egm_minmax egmframetype egmident egmstate egmstopmode errdomain errnum errstr errtype event_type exec_level extjoint handler_type icondata
identno intnum iodev iounit_state jointtarget listitem loaddata loadidnum loadsession
mecunit motsetdata num opcalc opnum orient paridnum paridvalidnum pathrecid pos pose progdisp
rawbytes restartdata rmqheader rmqmessage rmqslot robjoint robtarget shapedata signalai
signalao signaldi signaldo signalgi signalgo socketdev socketstatus speeddata stoppointdata
string stringdig switch symnum syncident system_data taskid tasks testsignal tooldata tpnum
trapdata triggdata triggios triggiosdnum triggstrgo tunetype uishownum wobjdata wzstationary
wztemporary zonedata
""")

#: Predefined data: constants and system data a module may use without declaring them.
PREDEFINED_DATA = _upper("""
tool0 wobj0 load0 ERRNO INTNO pi WAIT_MAX EOF_BIN EOF_NUM
ROB_1
EGM_FRAME_BASE EGM_FRAME_TOOL EGM_FRAME_WOBJ EGM_FRAME_WORLD EGM_FRAME_JOINT
EGM_STATE_DISCONNECTED EGM_STATE_CONNECTED EGM_STATE_RUNNING EGM_STOP_HOLD EGM_STOP_RAMP_DOWN
STR_DIGIT STR_UPPER STR_LOWER STR_WHITE
USINT UINT UDINT ULINT SINT INT DINT LINT
SOCKET_CREATED SOCKET_CONNECTED SOCKET_BOUND SOCKET_LISTENING SOCKET_CLOSED
fine vmax v5 v10 v20 v30 v40 v50 v60 v80 v100 v150 v200 v300 v400 v500 v600 v800 v1000
v1500 v2000 v2500 v3000 v4000 v5000 v6000 v7000
z0 z1 z5 z10 z15 z20 z30 z40 z50 z60 z80 z100 z150 z200
ERR_ALRDYCNT ERR_ARGDUPCND ERR_ARGNAME ERR_ARGNOTPER ERR_ARGNOTVAR ERR_AXIS_ACT ERR_AXIS_IND
ERR_AXIS_MOVING ERR_AXIS_PAR ERR_CALLPROC ERR_CFG_INTERNAL ERR_CFG_LIMIT ERR_CFG_ILLTYPE
ERR_CFG_NOTFND ERR_CFG_OUTOFBOUNDS ERR_CNTNOTVAR ERR_CNV_NOT_ACT ERR_CNV_CONNECT
ERR_CNV_DROPPED ERR_COLL_STOP ERR_DEV_MAXTIME ERR_DIVZERO ERR_EXECPHR ERR_FILEACC
ERR_FILEEXIST ERR_FILEOPEN ERR_FILNOTFND ERR_FNCNORET ERR_FRAME ERR_GO_LIM ERR_ILLDIM
ERR_ILLQUAT ERR_ILLRAISE ERR_INOMAX ERR_INVDIM ERR_IODISABLE ERR_IOENABLE ERR_IOERROR
ERR_LOADED ERR_LOADID_FATAL ERR_LOADID_RETRY ERR_MAXINTVAL ERR_MODULE ERR_MOD_NOT_LOADED
ERR_NAME_INVALID ERR_NORUNUNIT ERR_NOTARR ERR_NOTEQDIM ERR_NOTINTVAL ERR_NOTPRES
ERR_NOTSAVED ERR_OUTOFBND ERR_OUTSIDE_REACH ERR_OVERFLOW ERR_PATH ERR_PATHDIST
ERR_PATH_STOP ERR_PID_MOVESTOP ERR_PID_RAISE_PP ERR_PRGMEMFULL ERR_RANYBIN_CHK
ERR_RANYBIN_EOF ERR_RCVDATA ERR_REFUNKDAT ERR_REFUNKFUN ERR_REFUNKPRC ERR_REFUNKTRP
ERR_ROBLIMIT ERR_SC_WRITE ERR_SIGSUPSEARCH ERR_SIG_NAME ERR_SOCK_ADDR_INUSE ERR_SOCK_CLOSED
ERR_SOCK_IS_CONN ERR_SOCK_NET_UNREACH ERR_SOCK_NOT_CONN ERR_SOCK_TIMEOUT ERR_SOCK_UNSPEC
ERR_SPEEDLIM_VALUE ERR_STARTMOVE ERR_STRTOOLNG ERR_SYM_ACCESS ERR_SYNCMOVEOFF
ERR_SYNCMOVEON ERR_SYNTAX ERR_TASKNAME ERR_TP_DIBREAK ERR_TP_DOBREAK ERR_TP_MAXTIME
ERR_TP_NO_CLIENT ERR_TRUSTLEVEL ERR_TXTNOEXIST ERR_UNIT_PAR ERR_UNKINO ERR_UNKPROC ERR_UNLOAD
ERR_WAITSYNCTASK ERR_WAIT_MAXTIME ERR_WHLSEARCH ERR_WOBJ_MOVING
""")
