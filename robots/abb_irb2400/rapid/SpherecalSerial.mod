MODULE SpherecalSerial
  !----------------------------------------------------------------------
  ! spherecal link over a serial channel, for SpherecalServer.mod.
  !
  ! Load this module and SpherecalServer.mod into the same task, and no
  ! other spherecal link module. IRC5 (RobotWare 5, 6) and S4C+
  ! (RobotWare 4): only CHANNEL_NAME differs.
  !
  ! One line in: ReadStr waits for ever (\Time:=WAIT_MAX) and returns at
  ! the LF or after 80 characters. One line out: the text, then an LF.
  ! A channel that cannot be opened or fails ends the program with an
  ! error in the event log: nothing loops without a channel.
  !
  ! Global names: spherecal_link_open, spherecal_link_read,
  ! spherecal_link_write, spherecal_link_session. All else is LOCAL.
  !----------------------------------------------------------------------

  ! The transmission protocol named in the system parameters
  ! (Communication), with a colon. IRC5: "COM1:"; S4C+: "sio1:".
  LOCAL CONST string CHANNEL_NAME := "COM1:";

  LOCAL VAR iodev channel;
  LOCAL VAR bool channelOpen := FALSE;

  PROC spherecal_link_open()
    ! Opens the channel and discards what waits in its input buffer.
    IF channelOpen THEN
      ! Called again without a program reset: start from a fresh channel.
      Close channel;
      channelOpen := FALSE;
    ENDIF
    Open CHANNEL_NAME, channel \Bin;
    channelOpen := TRUE;
    ClearIOBuff channel;
  ERROR
    TEST ERRNO
    CASE ERR_FILEOPEN:
      ! A configuration fault. Say so and end the program: serving
      ! without a channel would spin without ever waiting.
      ErrWrite "SpherecalSerial: no serial channel",
        "Open " + CHANNEL_NAME + " failed."
        \RL2:="Set CHANNEL_NAME in SpherecalSerial to the"
        \RL3:="transmission protocol (Communication topic).";
      EXIT;
    DEFAULT:
      ChannelFailed "Open", ERRNO;
    ENDTEST
  ENDPROC

  PROC spherecal_link_read(VAR string text, VAR bool got)
    ! One line into text (got TRUE), or got FALSE and text "" when the
    ! read ends without one.
    got := FALSE;
    text := "";
    text := ReadStr(channel \Time:=WAIT_MAX);
    got := TRUE;
  ERROR
    TEST ERRNO
    CASE ERR_DEV_MAXTIME:
      ! No line for WAIT_MAX seconds: log it and return without a line;
      ! the server serves nothing and reads again.
      got := FALSE;
      text := "";
      ErrWrite \W, "SpherecalSerial: no request",
        "No line within WAIT_MAX s; reading again.";
      RETURN;
    DEFAULT:
      ! The channel failed: no reply can reach the PC.
      got := FALSE;
      text := "";
      ChannelFailed "ReadStr", ERRNO;
    ENDTEST
  ENDPROC

  PROC spherecal_link_write(string text)
    ! text (at most 80 characters), then the LF.
    WriteStrBin channel, text;
    WriteStrBin channel, "\0A";
  ERROR
    ! The channel failed while replying: nothing can reach the PC.
    ChannelFailed "WriteStrBin", ERRNO;
  ENDPROC

  FUNC num spherecal_link_session()
    ! A serial line has no connections: one session from open to exit.
    RETURN 1;
  ENDFUNC

  LOCAL PROC ChannelFailed(string what, num err)
    ! The channel does not work: say so in the event log and end the
    ! program (no loop may go on without a channel, and nothing is
    ! retried). Start again with PP to main once the fault is fixed.
    ErrWrite "SpherecalSerial: serial channel failed",
      what + " on " + CHANNEL_NAME + ": error " + NumToStr(err, 0);
    EXIT;
  ENDPROC
ENDMODULE
