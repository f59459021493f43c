MODULE SpherecalSocket
  !----------------------------------------------------------------------
  ! spherecal link over TCP, for SpherecalServer.mod: a socket server.
  !
  ! Load this module and SpherecalServer.mod into the same task, and no
  ! other spherecal link module. IRC5 only, with the RobotWare option
  ! that provides socket messaging (SocketCreate ... SocketSend): the
  ! PC Interface option on RobotWare 6 (Socket Messaging on early
  ! RobotWare 5). Without it the module does not load.
  !
  ! The server listens on SERVER_ADDRESS:SERVER_PORT and serves one PC
  ! at a time. The same lines as on the serial link: a line ends at its
  ! LF or after 80 characters; each reply goes out in one send.
  ! - When the PC closes the connection (or it breaks), the server logs
  !   it and waits for a new connection; nothing of the old one is kept,
  !   and a target staged over it cannot be moved to (a new session).
  ! - A reply that cannot be sent is lost with its connection; nothing
  !   is sent again.
  ! - Reads and accepts wait for ever (\Time:=WAIT_MAX); no error
  !   handler uses RETRY or TRYNEXT.
  ! - A socket that cannot be created, bound or listened on ends the
  !   program with an error in the event log.
  !
  ! Global names: spherecal_link_open, spherecal_link_read,
  ! spherecal_link_write, spherecal_link_session. All else is LOCAL.
  !----------------------------------------------------------------------

  ! The controller's own address on the PC's network (the LAN or WAN
  ! port's IP address; "127.0.0.1" on a RobotStudio virtual controller),
  ! and the TCP port the PC connects to (robot.port on the PC is
  ! "socket://SERVER_ADDRESS:SERVER_PORT").
  LOCAL CONST string SERVER_ADDRESS := "192.168.125.1";
  LOCAL CONST num SERVER_PORT := 5000;
  LOCAL CONST byte LF := 10;
  LOCAL CONST byte CR := 13;

  LOCAL VAR socketdev listener;
  LOCAL VAR socketdev client;
  LOCAL VAR bool connected := FALSE;
  ! Connections accepted since the program started.
  LOCAL VAR num session := 0;
  ! Bytes received and not yet taken (rx), and the next one to take.
  LOCAL VAR rawbytes rx;
  LOCAL VAR num rxNext := 1;
  LOCAL VAR rawbytes tx;

  PROC spherecal_link_open()
    ! Closes what an earlier start left open, then listens. The PC is
    ! accepted at the first read.
    SocketClose client;
    SocketClose listener;
    connected := FALSE;
    ClearRawBytes rx;
    rxNext := 1;
    SocketCreate listener;
    SocketBind listener, SERVER_ADDRESS, SERVER_PORT;
    SocketListen listener;
  ERROR
    ! A configuration fault (a wrong address, the port taken, no socket
    ! messaging): say so and end the program.
    LinkFailed "SocketCreate, SocketBind or SocketListen", ERRNO;
  ENDPROC

  PROC spherecal_link_read(VAR string text, VAR bool got)
    ! One line into text (got TRUE), or got FALSE and text "" when the
    ! read ends without one (the connection ended). Waits for a PC to
    ! connect first when none is connected.
    VAR byte b;
    got := FALSE;
    text := "";
    IF NOT connected Accept;
    IF NOT connected RETURN;
    WHILE NOT got DO
      IF rxNext > RawBytesLen(rx) THEN
        ClearRawBytes rx;
        rxNext := 1;
        SocketReceive client \RawData:=rx \Time:=WAIT_MAX;
      ENDIF
      UnpackRawBytes rx, rxNext, b \Hex1;
      Incr rxNext;
      IF b = LF THEN
        got := TRUE;
      ELSE
        ! Printable ASCII and CR as they are, any other byte as "?"
        ! (the checksum then fails, and the PC is told so).
        IF (b >= 32 AND b <= 126) OR b = CR THEN
          text := text + ByteToStr(b \Char);
        ELSE
          text := text + "?";
        ENDIF
        ! As ReadStr: 80 characters without an LF end the line.
        IF StrLen(text) >= 80 got := TRUE;
      ENDIF
    ENDWHILE
  ERROR
    got := FALSE;
    text := "";
    TEST ERRNO
    CASE ERR_SOCK_TIMEOUT:
      ! No byte for WAIT_MAX seconds: log it; the server reads again.
      ErrWrite \W, "SpherecalSocket: no request",
        "No line within WAIT_MAX s; reading again.";
      RETURN;
    DEFAULT:
      ! ERR_SOCK_CLOSED (the PC closed the connection, or it broke) or
      ! another socket error: end this connection, wait for a new one.
      Drop "SocketReceive", ERRNO;
      RETURN;
    ENDTEST
  ENDPROC

  PROC spherecal_link_write(string text)
    ! text (at most 80 characters) and the LF, in one send.
    IF NOT connected RETURN;
    ClearRawBytes tx;
    PackRawBytes text, tx, 1 \ASCII;
    PackRawBytes LF, tx, RawBytesLen(tx) + 1 \Hex1;
    SocketSend client \RawData:=tx;
  ERROR
    ! ERR_SOCK_CLOSED: the PC has gone. The reply is lost with the
    ! connection; the PC saw it close and sends nothing again.
    Drop "SocketSend", ERRNO;
    RETURN;
  ENDPROC

  FUNC num spherecal_link_session()
    ! Changes with every accepted connection.
    RETURN session;
  ENDFUNC

  LOCAL PROC Accept()
    ! Waits for the PC to connect. A new connection is a new session.
    VAR string peer := "";
    SocketAccept listener, client \ClientAddress:=peer \Time:=WAIT_MAX;
    connected := TRUE;
    Incr session;
    ClearRawBytes rx;
    rxNext := 1;
    ErrWrite \I, "SpherecalSocket: PC connected",
      "From " + peer + ", session " + NumToStr(session, 0) + ".";
  ERROR
    TEST ERRNO
    CASE ERR_SOCK_TIMEOUT:
      ! Nobody connected within WAIT_MAX s: the caller waits again.
      RETURN;
    DEFAULT:
      LinkFailed "SocketAccept", ERRNO;
    ENDTEST
  ENDPROC

  LOCAL PROC Drop(string what, num err)
    ! The connection ended: close it; the next read waits for a new one.
    IF err = ERR_SOCK_CLOSED THEN
      ErrWrite \I, "SpherecalSocket: PC disconnected",
        what + ": the connection was closed.";
    ELSE
      ErrWrite \W, "SpherecalSocket: connection failed",
        what + ": error " + NumToStr(err, 0) + "; closing it.";
    ENDIF
    SocketClose client;
    connected := FALSE;
    ClearRawBytes rx;
    rxNext := 1;
  ENDPROC

  LOCAL PROC LinkFailed(string what, num err)
    ! The server socket does not work: say so in the event log and end
    ! the program. Start again with PP to main once the fault is fixed.
    ErrWrite "SpherecalSocket: socket server failed",
      what + ": error " + NumToStr(err, 0)
      \RL2:="Check SERVER_ADDRESS and SERVER_PORT in SpherecalSocket"
      \RL3:="and the socket messaging (PC Interface) option.";
    EXIT;
  ENDPROC
ENDMODULE
