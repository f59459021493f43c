MODULE SpherecalServer
  !----------------------------------------------------------------------
  ! spherecal line protocol server, protocol version 3.
  !
  ! Serves the PC (spherecal, plugin abb_irb2400) one request line at a
  ! time; see docs/robot-abb-irb2400.md.
  !
  !   line    = body "*" XX LF   (XX: XOR of the body's bytes, 2 hex digits)
  !   request = PING seq token | GETJ seq | GETP seq
  !           | TGT seq x y z q1 q2 q3 q4 | MOVL seq speed target_seq v_ori
  !           | SSTART seq period_ms | SSTOP seq
  !           | LSTART seq reset distance_mm | LSTOP seq | LTIME seq
  !   reply   = PONG seq 3 token | J seq j1..j6 | P seq x y z q1 q2 q3 q4
  !           | T seq moves start_ms cruise_end_ms end_ms
  !           | OK seq | ERR seq code text      (seq "-" if unreadable)
  !
  ! A line holds at most 80 characters before its LF (a RAPID string).
  ! The PC opens each session with PING and a token of its own (1 to 12
  ! lower-case hex digits); PONG echoes it. Lines are served one after
  ! another, so the PC takes no reply before that PONG for its own.
  ! Poses are tool0 in wobj0 (base_from_flange), mm; the quaternion is
  ! [q1, q2, q3, q4] = (w, x, y, z). Joints are CJointT() values, deg.
  ! RAPID num is a 32-bit float: about 7 significant digits, so
  ! 1234.567 mm is resolved to about 0.0001 mm and a quaternion
  ! component to about 1E-7.
  !
  ! The link to the PC is a second module, loaded with this one: exactly
  ! one of SpherecalSerial.mod (a serial channel; IRC5 and S4C+) or
  ! SpherecalSocket.mod (a TCP socket server; IRC5 with the PC Interface
  ! option). It provides spherecal_link_open, spherecal_link_read,
  ! spherecal_link_write and spherecal_link_session.
  !
  ! SSTART and SSTOP start and stop the pose stream over Externally
  ! Guided Motion (read-only: the arm moves by MOVL as ever). They call
  ! SpherecalEgm.mod by name, so this module loads without it (and
  ! without the EGM option); the server then answers them with ERR 7.
  !
  ! LSTART, LSTOP and LTIME turn on and off, and read, the stamps of the
  ! programmed-line stream (SpherecalLine.mod, for a controller without
  ! EGM such as the S4C+): while on, MOVL moves by spherecal_line_move,
  ! a stamped TriggL, and LTIME answers T with the last move's stamps.
  ! Called by name too: without the module, ERR 7.
  !
  ! Entry routine: spherecal_server_main. Call it from your main, or make
  ! it the entry routine of the task. The optional event routine
  ! spherecal_server_on_stop tells the PC at once when the program stops
  ! during a move. Every other name here is LOCAL to this module, so it
  ! cannot clash with the names of your own modules.
  !
  ! Safety rules (checked by tests/robots/test_irb2400_rapid_server.py):
  ! - the line is cleared before every read, and the read waits for ever
  !   (\Time:=WAIT_MAX): a line is served once, when it arrives;
  ! - no error handler uses RETRY or TRYNEXT, so nothing is run again
  !   after an error, least of all a move; a failed read serves nothing;
  ! - a target is moved to once: a MOVL naming a target already reached
  !   answers OK without moving;
  ! - a target is moved to only over the link session that staged it
  !   (a new socket connection starts with no target);
  ! - no SkipWarn: every error stays in the event log.
  !
  ! Controllers: IRC5 (RobotWare 5, 6) and S4C+ (RobotWare 4, serial
  ! link only). Not yet run on either; see the docs.
  !----------------------------------------------------------------------

  LOCAL CONST num PROTOCOL_VERSION := 3;
  ! The characters of a session token, and the most it may have.
  LOCAL CONST string TOKEN_CHARS := "0123456789abcdef";
  LOCAL CONST num TOKEN_MAX := 12;
  ! Largest TCP speed a MOVL may ask for, mm/s.
  LOCAL CONST num MAX_SPEED := 1000;
  ! Largest reorientation speed a MOVL may ask for, deg/s.
  LOCAL CONST num MAX_ORI_SPEED := 500;
  ! Error codes (ErrorCode in protocol.py).
  LOCAL CONST num E_CHECKSUM := 1;
  LOCAL CONST num E_SYNTAX := 2;
  LOCAL CONST num E_RANGE := 3;
  LOCAL CONST num E_NO_TARGET := 4;
  LOCAL CONST num E_UNREACHABLE := 5;
  LOCAL CONST num E_MOTION := 6;
  ! A stream request failed on the controller (the IRB 2400's server).
  LOCAL CONST num E_STREAM := 7;
  ! Longest sample period a SSTART may ask for, ms (a multiple of 4).
  LOCAL CONST num MAX_SAMPLE_MS := 100;
  ! Largest stamp distance a LSTART may ask for, mm.
  LOCAL CONST num MAX_STAMP_DIST := 500;

  ! The request line being served, and whether the last read gave one.
  LOCAL VAR string line := "";
  LOCAL VAR bool haveLine := FALSE;
  LOCAL VAR string fields{10};
  LOCAL VAR num nFields := 0;
  ! The staged target, its seq, the link session that staged it, and
  ! whether it has been moved to.
  LOCAL VAR robtarget target;
  LOCAL VAR num targetSeq := -1;
  LOCAL VAR num targetSession := -1;
  LOCAL VAR bool targetReached := FALSE;
  ! Whether MOVL moves stamped (LSTART .. LSTOP; SpherecalLine.mod).
  LOCAL VAR bool lineOn := FALSE;
  ! The seq of the MOVL being executed ("" when no move is under way).
  LOCAL VAR string movingSeq := "";
  LOCAL VAR speeddata moveSpeed := [100, 500, 5000, 1000];

  ! --- entry -------------------------------------------------------------
  PROC spherecal_server_main()
    ! Serves for ever; leaves only through an error it cannot recover from
    ! (the error is then in the event log and the program stops).
    spherecal_link_open;
    ConfL \Off;
    movingSeq := "";
    WHILE TRUE DO
      ReadRequest;
      IF haveLine Serve line;
    ENDWHILE
  ENDPROC

  PROC spherecal_server_on_stop()
    ! Optional event routine for STOP and QSTOP (system parameters,
    ! Controller, Event Routine): if the program stops during a move, the
    ! PC gets ERR 6 now instead of waiting for its timeout. If the program
    ! is started again, the controller finishes the interrupted move and
    ! then sends its OK, which the PC discards as stale.
    IF movingSeq <> "" THEN
      ReplyError movingSeq, E_MOTION, "program stopped during the move";
      movingSeq := "";
    ENDIF
  ENDPROC

  ! --- reading ---------------------------------------------------------
  LOCAL PROC ReadRequest()
    ! One line, waiting for ever. The line is cleared first, so a read
    ! that ends without a line can never leave the previous line behind
    ! to be served. The link module handles its own errors: a read that
    ! fails, times out or loses its connection returns haveLine FALSE.
    haveLine := FALSE;
    line := "";
    spherecal_link_read line, haveLine;
    ! A CR before the LF is ignored (done here: S4C+ lacks \RemoveCR).
    IF haveLine AND StrLen(line) > 0 THEN
      IF StrPart(line, StrLen(line), 1) = "\0D" THEN
        line := StrPart(line, 1, StrLen(line) - 1);
      ENDIF
    ENDIF
  ENDPROC

  ! --- framing -----------------------------------------------------------
  LOCAL FUNC string Checksum(string body)
    VAR byte x := 0;
    VAR string hex;
    FOR i FROM 1 TO StrLen(body) DO
      x := BitXOr(x, StrToByte(StrPart(body, i, 1) \Char));
    ENDFOR
    hex := StrMap(ByteToStr(x \Hex), "abcdef", "ABCDEF");
    IF StrLen(hex) < 2 hex := "0" + hex;
    RETURN hex;
  ENDFUNC

  LOCAL PROC Reply(string body)
    ! body + "*XX" is at most 80 characters; the link adds the LF.
    spherecal_link_write body + "*" + Checksum(body);
  ENDPROC

  LOCAL PROC ReplyError(string seqText, num code, string text)
    Reply "ERR " + seqText + " " + NumToStr(code, 0) + " " + text;
  ENDPROC

  LOCAL PROC Split(string body)
    VAR num pos := 1;
    VAR num space;
    nFields := 0;
    WHILE pos <= StrLen(body) AND nFields < 10 DO
      space := StrFind(body, pos, " ");
      Incr nFields;
      fields{nFields} := StrPart(body, pos, space - pos);
      pos := space + 1;
    ENDWHILE
  ENDPROC

  ! --- requests ----------------------------------------------------------
  LOCAL PROC Serve(string request)
    VAR num star;
    VAR string body;
    VAR string kind;
    VAR string seqText := "-";
    VAR num seq;
    VAR num want;
    star := StrFind(request, 1, "*");
    IF star < 2 OR StrLen(request) - star <> 2 THEN
      ReplyError "-", E_SYNTAX, "no checksum";
      RETURN;
    ENDIF
    body := StrPart(request, 1, star - 1);
    IF StrMap(StrPart(request, star + 1, 2), "abcdef", "ABCDEF")
        <> Checksum(body) THEN
      ReplyError "-", E_CHECKSUM, "bad checksum";
      RETURN;
    ENDIF
    Split body;
    IF nFields < 2 THEN
      ReplyError "-", E_SYNTAX, "no sequence number";
      RETURN;
    ENDIF
    kind := fields{1};
    ! The seq is echoed in every reply: 1 to 3 digits, so that no reply
    ! can outgrow a RAPID string.
    IF StrLen(fields{2}) < 1 OR StrLen(fields{2}) > 3
        OR StrFind(fields{2}, 1, STR_DIGIT \NotInSet) <= StrLen(fields{2})
        THEN
      ReplyError "-", E_SYNTAX, "bad sequence number";
      RETURN;
    ENDIF
    seqText := fields{2};
    IF NOT StrToVal(seqText, seq) THEN
      ReplyError "-", E_SYNTAX, "bad sequence number";
      RETURN;
    ENDIF
    TEST kind
    CASE "PING":
      want := 3;
    CASE "GETJ":
      want := 2;
    CASE "GETP":
      want := 2;
    CASE "TGT":
      want := 9;
    CASE "MOVL":
      want := 5;
    CASE "SSTART":
      want := 3;
    CASE "SSTOP":
      want := 2;
    CASE "LSTART":
      want := 4;
    CASE "LSTOP":
      want := 2;
    CASE "LTIME":
      want := 2;
    DEFAULT:
      ReplyError seqText, E_SYNTAX, "unknown request";
      RETURN;
    ENDTEST
    IF nFields <> want THEN
      ReplyError seqText, E_SYNTAX, "wrong number of fields";
      RETURN;
    ENDIF
    TEST kind
    CASE "PING":
      ! The token is echoed as it came, once it is known to be short hex.
      IF StrLen(fields{3}) > TOKEN_MAX
          OR StrFind(fields{3}, 1, TOKEN_CHARS \NotInSet)
          <= StrLen(fields{3}) THEN
        ReplyError seqText, E_SYNTAX, "bad session token";
        RETURN;
      ENDIF
      Reply "PONG " + seqText + " " + NumToStr(PROTOCOL_VERSION, 0)
        + " " + fields{3};
    CASE "GETJ":
      SendJoints seqText;
    CASE "GETP":
      SendPose seqText;
    CASE "TGT":
      StageTarget seq, seqText;
    CASE "MOVL":
      MoveToTarget seqText;
    CASE "SSTART":
      StartStream seqText;
    CASE "SSTOP":
      StopStream seqText;
    CASE "LSTART":
      StartLine seqText;
    CASE "LSTOP":
      StopLine seqText;
    CASE "LTIME":
      SendLineStamps seqText;
    ENDTEST
  ERROR
    ! Any error of this request (the link handles its own): log it,
    ! answer it, and serve the next line. The request is not run again.
    ErrWrite \W, "SpherecalServer: request failed",
      "Seq " + seqText + ": error " + NumToStr(ERRNO, 0);
    ReplyError seqText, E_SYNTAX, "request failed, error "
      + NumToStr(ERRNO, 0);
    RETURN;
  ENDPROC

  LOCAL PROC SendJoints(string seqText)
    VAR jointtarget j;
    ! WaitTime \InPos rather than WaitRob: the S4C+ has no WaitRob.
    WaitTime \InPos, 0;
    j := CJointT();
    Reply "J " + seqText + " " + NumToStr(j.robax.rax_1, 4)
      + " " + NumToStr(j.robax.rax_2, 4) + " " + NumToStr(j.robax.rax_3, 4)
      + " " + NumToStr(j.robax.rax_4, 4) + " " + NumToStr(j.robax.rax_5, 4)
      + " " + NumToStr(j.robax.rax_6, 4);
  ENDPROC

  LOCAL PROC SendPose(string seqText)
    VAR robtarget p;
    WaitTime \InPos, 0;
    p := CRobT(\Tool:=tool0 \WObj:=wobj0);
    Reply "P " + seqText + " " + NumToStr(p.trans.x, 3)
      + " " + NumToStr(p.trans.y, 3) + " " + NumToStr(p.trans.z, 3)
      + " " + NumToStr(p.rot.q1, 6) + " " + NumToStr(p.rot.q2, 6)
      + " " + NumToStr(p.rot.q3, 6) + " " + NumToStr(p.rot.q4, 6);
  ENDPROC

  LOCAL PROC StageTarget(num seq, string seqText)
    VAR num v{7};
    VAR robtarget now;
    FOR i FROM 1 TO 7 DO
      IF NOT StrToVal(fields{i + 2}, v{i}) THEN
        ReplyError seqText, E_SYNTAX, "bad number";
        RETURN;
      ENDIF
    ENDFOR
    now := CRobT(\Tool:=tool0 \WObj:=wobj0);
    target := now;
    target.trans := [v{1}, v{2}, v{3}];
    target.rot := NOrient([v{4}, v{5}, v{6}, v{7}]);
    targetSeq := seq;
    targetSession := spherecal_link_session();
    targetReached := FALSE;
    Reply "OK " + seqText;
  ENDPROC

  LOCAL FUNC bool Reachable(robtarget t)
    VAR jointtarget j;
    j := CalcJointT(t, tool0 \WObj:=wobj0);
    RETURN TRUE;
  ERROR
    TEST ERRNO
    CASE ERR_ROBLIMIT:
      ! Out of reach or beyond a joint limit. The controller's warning
      ! stays in the event log; the PC gets code 5.
      RETURN FALSE;
    DEFAULT:
      ! Any other error (ERR_OUTSIDE_REACH on newer RobotWare) goes to
      ! MoveToTarget, which answers code 6 with the error number.
      RAISE;
    ENDTEST
  ENDFUNC

  LOCAL PROC MoveToTarget(string seqText)
    VAR num speed;
    VAR num tseq;
    VAR num oriSpeed;
    IF NOT StrToVal(fields{3}, speed) OR NOT StrToVal(fields{4}, tseq)
        OR NOT StrToVal(fields{5}, oriSpeed) THEN
      ReplyError seqText, E_SYNTAX, "bad number";
      RETURN;
    ENDIF
    IF speed <= 0 OR speed > MAX_SPEED THEN
      ReplyError seqText, E_RANGE, "speed outside 0.."
        + NumToStr(MAX_SPEED, 0);
      RETURN;
    ENDIF
    IF oriSpeed <= 0 OR oriSpeed > MAX_ORI_SPEED THEN
      ReplyError seqText, E_RANGE, "orientation speed outside 0.."
        + NumToStr(MAX_ORI_SPEED, 0);
      RETURN;
    ENDIF
    IF tseq <> targetSeq OR targetSession <> spherecal_link_session() THEN
      ! (a target staged over an earlier connection does not count)
      ReplyError seqText, E_NO_TARGET, "no such target staged";
      RETURN;
    ENDIF
    IF targetReached THEN
      ! Moved there already: a MOVL resent after a lost reply, or one left
      ! over in the buffer. Never move to the same target twice (the arm
      ! may have been jogged since).
      Reply "OK " + seqText;
      RETURN;
    ENDIF
    IF NOT Reachable(target) THEN
      ReplyError seqText, E_UNREACHABLE,
        "target out of reach or beyond a joint limit";
      RETURN;
    ENDIF
    ! Both speeds as the PC chose them: the sensor, off the flange, moves
    ! within the move's speed (tool0 alone would limit only the flange).
    moveSpeed.v_tcp := speed;
    moveSpeed.v_ori := oriSpeed;
    movingSeq := seqText;
    IF lineOn THEN
      ! Stamped: the same MoveL as a TriggL (SpherecalLine.mod).
      %"spherecal_line_move"% target, moveSpeed;
    ELSE
      MoveL target, moveSpeed, fine, tool0 \WObj:=wobj0;
    ENDIF
    WaitTime \InPos, 0;
    targetReached := TRUE;
    movingSeq := "";
    Reply "OK " + seqText;
  ERROR
    ! Errors that reach this handler (a motion error that stops the
    ! program does not): clear what is left of the move and answer.
    ! Never RETRY or TRYNEXT here: either would move without a request.
    movingSeq := "";
    StopMove;
    ClearPath;
    StartMove;
    ErrWrite \W, "SpherecalServer: move failed",
      "MOVL " + seqText + ": error " + NumToStr(ERRNO, 0);
    ReplyError seqText, E_MOTION, "motion error " + NumToStr(ERRNO, 0);
    RETURN;
  ENDPROC

  ! --- the pose stream (SpherecalEgm.mod) ---------------------------------
  LOCAL PROC StartStream(string seqText)
    ! SSTART: the EGM stream, one sample every periodMs. Moves nothing.
    VAR num periodMs;
    IF NOT StrToVal(fields{3}, periodMs) THEN
      ReplyError seqText, E_SYNTAX, "bad number";
      RETURN;
    ENDIF
    IF periodMs < 4 OR periodMs > MAX_SAMPLE_MS
        OR Trunc(periodMs / 4) * 4 <> periodMs THEN
      ReplyError seqText, E_RANGE, "sample period not a multiple of 4 in 4.."
        + NumToStr(MAX_SAMPLE_MS, 0);
      RETURN;
    ENDIF
    %"spherecal_egm_start"% periodMs;
    Reply "OK " + seqText;
  ERROR
    StreamFailed "SSTART", seqText, ERRNO;
    RETURN;
  ENDPROC

  LOCAL PROC StopStream(string seqText)
    ! SSTOP: stop the EGM stream (OK also when none runs).
    %"spherecal_egm_stop"%;
    Reply "OK " + seqText;
  ERROR
    StreamFailed "SSTOP", seqText, ERRNO;
    RETURN;
  ENDPROC

  ! --- the programmed-line stream (SpherecalLine.mod) ---------------------
  LOCAL PROC StartLine(string seqText)
    ! LSTART: stamp every following MOVL where its path passes distance
    ! mm from its start; reset 1 restarts the clock. Moves nothing.
    VAR num reset;
    VAR num distance;
    IF NOT StrToVal(fields{3}, reset) OR NOT StrToVal(fields{4}, distance)
        THEN
      ReplyError seqText, E_SYNTAX, "bad number";
      RETURN;
    ENDIF
    IF reset <> 0 AND reset <> 1 THEN
      ReplyError seqText, E_RANGE, "reset not 0 or 1";
      RETURN;
    ENDIF
    IF distance < 0 OR distance > MAX_STAMP_DIST THEN
      ReplyError seqText, E_RANGE, "distance outside 0.."
        + NumToStr(MAX_STAMP_DIST, 0);
      RETURN;
    ENDIF
    %"spherecal_line_start"% reset, distance;
    lineOn := TRUE;
    Reply "OK " + seqText;
  ERROR
    lineOn := FALSE;
    StreamFailed "LSTART", seqText, ERRNO;
    RETURN;
  ENDPROC

  LOCAL PROC StopLine(string seqText)
    ! LSTOP: MOVL moves unstamped again (OK also when not stamping).
    lineOn := FALSE;
    %"spherecal_line_stop"%;
    Reply "OK " + seqText;
  ERROR
    StreamFailed "LSTOP", seqText, ERRNO;
    RETURN;
  ENDPROC

  LOCAL PROC SendLineStamps(string seqText)
    ! LTIME: T seq moves start_ms cruise_end_ms end_ms (-1: a stamp not
    ! taken).
    VAR num n := 0;
    VAR num tStart := -1;
    VAR num tCruiseEnd := -1;
    VAR num tEnd := -1;
    %"spherecal_line_stamps"% n, tStart, tCruiseEnd, tEnd;
    Reply "T " + seqText + " " + NumToStr(n, 0) + " "
      + NumToStr(tStart, 0) + " " + NumToStr(tCruiseEnd, 0) + " "
      + NumToStr(tEnd, 0);
  ERROR
    StreamFailed "LTIME", seqText, ERRNO;
    RETURN;
  ENDPROC

  LOCAL PROC StreamFailed(string kind, string seqText, num err)
    ! Answers a stream request that failed with error err: ERR 7.
    IF err = ERR_REFUNKPRC OR err = ERR_CALLPROC THEN
      ! The late-bound routine is not there: the module is not loaded.
      IF StrPart(kind, 1, 1) = "L" THEN
        ReplyError seqText, E_STREAM, "SpherecalLine.mod is not loaded";
        RETURN;
      ENDIF
      ReplyError seqText, E_STREAM, "SpherecalEgm.mod is not loaded";
    ELSE
      ErrWrite \W, "SpherecalServer: stream failed",
        kind + " " + seqText + ": error " + NumToStr(err, 0);
      ReplyError seqText, E_STREAM, "stream error " + NumToStr(err, 0);
    ENDIF
  ENDPROC
ENDMODULE
