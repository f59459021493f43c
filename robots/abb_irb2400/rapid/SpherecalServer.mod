MODULE SpherecalServer
  !------------------------------------------------------------------------
  ! spherecal line protocol server, protocol version 1.
  !
  ! Serves the PC (spherecal, plugin abb_irb2400) over a serial channel.
  ! One request line in, one reply line out; see docs/robot-abb-irb2400.md.
  !
  !   line    = body "*" XX LF   (XX: XOR of the body's bytes, 2 hex digits)
  !   request = PING seq | GETJ seq | GETP seq
  !           | TGT seq x y z q1 q2 q3 q4 | MOVL seq speed target_seq
  !   reply   = PONG seq 1 | J seq j1..j6 | P seq x y z q1 q2 q3 q4
  !           | OK seq | ERR seq code text      (seq "-" if unreadable)
  !
  ! A line holds at most 80 characters before its LF (a RAPID string).
  ! Poses are tool0 in wobj0 (base_from_flange), mm; the quaternion is
  ! [q1, q2, q3, q4] = (w, x, y, z). Joints are CJointT() values, deg.
  ! RAPID num is a 32-bit float: about 7 significant digits, so
  ! 1234.567 mm is resolved to about 0.0001 mm and a quaternion
  ! component to about 1E-7.
  !------------------------------------------------------------------------

  ! Serial channel as named in the system parameters (Communication).
  CONST string CHANNEL_NAME := "com1:";
  CONST num PROTOCOL_VERSION := 1;
  ! Largest TCP speed a MOVL may ask for, mm/s.
  CONST num MAX_SPEED := 1000;
  ! Error codes (ErrorCode in protocol.py).
  CONST num E_CHECKSUM := 1;
  CONST num E_SYNTAX := 2;
  CONST num E_RANGE := 3;
  CONST num E_NO_TARGET := 4;
  CONST num E_UNREACHABLE := 5;
  CONST num E_MOTION := 6;

  VAR iodev channel;
  VAR string fields{10};
  VAR num nFields := 0;
  VAR robtarget target;
  VAR num targetSeq := -1;
  VAR speeddata moveSpeed := [100, 500, 5000, 1000];

  PROC main()
    VAR string line;
    ConfL \Off;
    Open CHANNEL_NAME, channel \Bin;
    ClearIOBuff channel;
    WHILE TRUE DO
      line := ReadStr(channel \RemoveCR);
      Serve line;
    ENDWHILE
  ERROR
    ! A channel error: skip it and keep serving.
    TRYNEXT;
  ENDPROC

  ! --- framing -------------------------------------------------------------
  FUNC string Checksum(string body)
    VAR byte x := 0;
    VAR string hex;
    FOR i FROM 1 TO StrLen(body) DO
      x := BitXOr(x, StrToByte(StrPart(body, i, 1) \Char));
    ENDFOR
    hex := StrMap(ByteToStr(x \Hex), "abcdef", "ABCDEF");
    IF StrLen(hex) < 2 hex := "0" + hex;
    RETURN hex;
  ENDFUNC

  PROC Reply(string body)
    ! body + "*XX" is at most 80 characters; the LF goes separately.
    WriteStrBin channel, body + "*" + Checksum(body);
    WriteStrBin channel, "\0A";
  ENDPROC

  PROC ReplyError(string seqText, num code, string text)
    Reply "ERR " + seqText + " " + NumToStr(code, 0) + " " + text;
  ENDPROC

  PROC Split(string body)
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

  ! --- requests ------------------------------------------------------------
  PROC Serve(string line)
    VAR num star;
    VAR string body;
    VAR string kind;
    VAR string seqText;
    VAR num seq;
    star := StrFind(line, 1, "*");
    IF star < 2 OR StrLen(line) - star <> 2 THEN
      ReplyError "-", E_SYNTAX, "no checksum";
      RETURN;
    ENDIF
    body := StrPart(line, 1, star - 1);
    IF StrMap(StrPart(line, star + 1, 2), "abcdef", "ABCDEF") <> Checksum(body) THEN
      ReplyError "-", E_CHECKSUM, "bad checksum";
      RETURN;
    ENDIF
    Split body;
    IF nFields < 2 THEN
      ReplyError "-", E_SYNTAX, "no sequence number";
      RETURN;
    ENDIF
    kind := fields{1};
    seqText := fields{2};
    IF NOT StrToVal(seqText, seq) THEN
      ReplyError "-", E_SYNTAX, "bad sequence number";
      RETURN;
    ENDIF
    TEST kind
    CASE "PING":
      IF nFields <> 2 GOTO wrongCount;
      Reply "PONG " + seqText + " " + NumToStr(PROTOCOL_VERSION, 0);
    CASE "GETJ":
      IF nFields <> 2 GOTO wrongCount;
      SendJoints seqText;
    CASE "GETP":
      IF nFields <> 2 GOTO wrongCount;
      SendPose seqText;
    CASE "TGT":
      IF nFields <> 9 GOTO wrongCount;
      StageTarget seq, seqText;
    CASE "MOVL":
      IF nFields <> 4 GOTO wrongCount;
      MoveToTarget seqText;
    DEFAULT:
      ReplyError seqText, E_SYNTAX, "unknown request";
    ENDTEST
    RETURN;
  wrongCount:
    ReplyError seqText, E_SYNTAX, "wrong number of fields";
  ENDPROC

  PROC SendJoints(string seqText)
    VAR jointtarget j;
    WaitRob \InPos;
    j := CJointT();
    Reply "J " + seqText + " " + NumToStr(j.robax.rax_1, 4) + " " + NumToStr(j.robax.rax_2, 4)
      + " " + NumToStr(j.robax.rax_3, 4) + " " + NumToStr(j.robax.rax_4, 4)
      + " " + NumToStr(j.robax.rax_5, 4) + " " + NumToStr(j.robax.rax_6, 4);
  ENDPROC

  PROC SendPose(string seqText)
    VAR robtarget p;
    WaitRob \InPos;
    p := CRobT(\Tool:=tool0 \WObj:=wobj0);
    Reply "P " + seqText + " " + NumToStr(p.trans.x, 3) + " " + NumToStr(p.trans.y, 3)
      + " " + NumToStr(p.trans.z, 3) + " " + NumToStr(p.rot.q1, 6) + " " + NumToStr(p.rot.q2, 6)
      + " " + NumToStr(p.rot.q3, 6) + " " + NumToStr(p.rot.q4, 6);
  ENDPROC

  PROC StageTarget(num seq, string seqText)
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
    Reply "OK " + seqText;
  ENDPROC

  FUNC bool Reachable(robtarget t)
    VAR jointtarget j;
    j := CalcJointT(t, tool0 \WObj:=wobj0);
    RETURN TRUE;
  ERROR
    ! ERR_ROBLIMIT (and, on newer RobotWare, ERR_OUTSIDE_REACH).
    SkipWarn;
    RETURN FALSE;
  ENDFUNC

  PROC MoveToTarget(string seqText)
    VAR num speed;
    VAR num tseq;
    IF NOT StrToVal(fields{3}, speed) OR NOT StrToVal(fields{4}, tseq) THEN
      ReplyError seqText, E_SYNTAX, "bad number";
      RETURN;
    ENDIF
    IF speed <= 0 OR speed > MAX_SPEED THEN
      ReplyError seqText, E_RANGE, "speed outside 0.." + NumToStr(MAX_SPEED, 0);
      RETURN;
    ENDIF
    IF tseq <> targetSeq THEN
      ReplyError seqText, E_NO_TARGET, "no target " + fields{4} + " staged";
      RETURN;
    ENDIF
    IF NOT Reachable(target) THEN
      ReplyError seqText, E_UNREACHABLE, "target out of reach or beyond a joint limit";
      RETURN;
    ENDIF
    moveSpeed.v_tcp := speed;
    MoveL target, moveSpeed, fine, tool0 \WObj:=wobj0;
    WaitRob \InPos;
    Reply "OK " + seqText;
  ERROR
    SkipWarn;
    ReplyError seqText, E_MOTION, "motion error " + NumToStr(ERRNO, 0);
    RETURN;
  ENDPROC
ENDMODULE
