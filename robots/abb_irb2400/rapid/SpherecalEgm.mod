MODULE SpherecalEgm
  !----------------------------------------------------------------------
  ! spherecal pose streaming over Externally Guided Motion (EGM), for
  ! SpherecalServer.mod, whose SSTART and SSTOP call the two routines
  ! below. Position streaming only: the controller sends the measured
  ! pose and joints every sample period over UDP while the server's
  ! ordinary MoveL run; EGM never moves the arm here (no EGMRunPose).
  !
  ! Needs an IRC5 with RobotWare 6.07 or later and the option
  ! Externally Guided Motion (689-1): without it this module does not
  ! load, and the server answers SSTART with ERR 7. Load it into the
  ! same task as SpherecalServer.mod and its link module.
  !
  ! The samples go to the UDPUC transmission protocol named EGM_DEVICE
  ! (system parameters, topic Communication): its remote address is
  ! the PC's address, its remote port robot.egm.port on the PC.
  ! The feedback pose is tool0 in wobj0 (EGMActPose below), as GETP
  ! reports it; the PC checks that on every start.
  !
  ! Global names: spherecal_egm_start, spherecal_egm_stop. All else is
  ! LOCAL.
  !----------------------------------------------------------------------

  ! The UDPUC transmission protocol that leads to the PC.
  LOCAL CONST string EGM_DEVICE := "SpherecalPC";
  ! The EGM configuration (system parameters, topic Motion, External
  ! Motion Interface Data) the channel uses.
  LOCAL CONST string EGM_CONFIG := "default";
  ! Correction and sensor frames: wobj0 itself.
  LOCAL CONST pose FRAME_WOBJ := [[0, 0, 0], [1, 0, 0, 0]];

  LOCAL VAR egmident egmId;
  LOCAL VAR bool setUp := FALSE;
  LOCAL VAR bool streaming := FALSE;

  PROC spherecal_egm_start(num periodMs)
    ! Sets the channel up on the first start, then starts the stream
    ! (again, if one runs) with one sample every periodMs (4, 8, ...).
    IF NOT setUp THEN
      EGMGetId egmId;
      EGMSetupUC ROB_1, egmId, EGM_CONFIG, EGM_DEVICE \Pose;
      EGMActPose egmId \Tool:=tool0 \WObj:=wobj0, FRAME_WOBJ,
        EGM_FRAME_WOBJ, FRAME_WOBJ, EGM_FRAME_WOBJ;
      setUp := TRUE;
    ENDIF
    IF streaming THEN
      EGMStreamStop egmId;
      streaming := FALSE;
    ENDIF
    EGMStreamStart egmId \SampleRate:=periodMs;
    streaming := TRUE;
  ERROR
    ! An EGM error (the device, the configuration): the next start sets
    ! the channel up again; the server answers ERR 7 with the number.
    setUp := FALSE;
    streaming := FALSE;
    ErrWrite \W, "SpherecalEgm: stream not started",
      "Error " + NumToStr(ERRNO, 0) + "; check EGM_DEVICE and the option.";
    RAISE;
  ENDPROC

  PROC spherecal_egm_stop()
    ! Stops the stream; nothing to do when none runs.
    IF streaming THEN
      EGMStreamStop egmId;
    ENDIF
    streaming := FALSE;
  ERROR
    streaming := FALSE;
    ErrWrite \W, "SpherecalEgm: stream not stopped",
      "Error " + NumToStr(ERRNO, 0) + ".";
    RAISE;
  ENDPROC
ENDMODULE
