MODULE SpherecalLine
  !----------------------------------------------------------------------
  ! spherecal programmed-line pose stream, for SpherecalServer.mod, whose
  ! LSTART, LSTOP and LTIME call the routines below, and whose MOVL calls
  ! spherecal_line_move while stamping is on. For a controller that
  ! cannot stream its pose (S4C+, RobotWare 4; an IRC5 without EGM): it
  ! sends no poses. It stamps, with its own clock, when each move's path
  ! passes a distance from its start point (past the acceleration ramp)
  ! and when the arm is in position at its end; the PC computes the pose
  ! at any time along the programmed line.
  !
  ! The start stamp: TriggL with a TriggInt at stampDist mm from the
  ! start point (\Start); its trap routine reads the clock. A second
  ! TriggInt stamps the path stampDist mm before its end point (the PC
  ! checks the speed between the two). The end: the
  ! clock read once the fine point is reached (WaitTime \InPos). The
  ! clock: a RAPID clock, reset and started by an LSTART that asks for
  ! it (the PC's first stream of a connection), read in whole ms.
  !
  ! Assumed, not verified on a controller: TriggL, TriggInt, CONNECT and
  ! the clock instructions behave on RobotWare 4 (S4C+) as the RobotWare
  ! 5 and 6 manuals describe them (on some S4C+ systems the Trigg
  ! instructions are the option Fixed Position Events); ClkRead counts
  ! in steps of 1 ms or finer; the trap runs a constant time after the
  ! path passes the distance: the constant part is in the clock offset
  ! the PC estimates, the part that varies from move to move is not.
  !
  ! Global names: spherecal_line_start, spherecal_line_stop,
  ! spherecal_line_move, spherecal_line_stamps. All else is LOCAL.
  !----------------------------------------------------------------------

  LOCAL VAR clock lineClock;
  LOCAL VAR intnum startInt;
  LOCAL VAR intnum cruiseEndInt;
  LOCAL VAR bool connected := FALSE;
  LOCAL VAR triggdata startTrigg;
  LOCAL VAR triggdata cruiseEndTrigg;
  ! Where along each path the start stamp is taken, mm from its start.
  LOCAL VAR num stampDist := 0;
  ! Moves stamped since LSTART; the last one's stamps, ms (-1: not taken).
  LOCAL VAR num moves := 0;
  LOCAL VAR num startMs := -1;
  LOCAL VAR num cruiseEndMs := -1;
  LOCAL VAR num endMs := -1;

  PROC spherecal_line_start(num resetClock, num distMm)
    ! Stamping on, distMm along each path; resetClock 1 restarts the
    ! clock from zero.
    IF NOT connected THEN
      CONNECT startInt WITH StartTrap;
      CONNECT cruiseEndInt WITH CruiseEndTrap;
      connected := TRUE;
    ENDIF
    IF resetClock = 1 THEN
      ClkReset lineClock;
      ClkStart lineClock;
    ENDIF
    stampDist := distMm;
    moves := 0;
    startMs := -1;
    cruiseEndMs := -1;
    endMs := -1;
  ENDPROC

  PROC spherecal_line_stop()
    ! Stamping off: nothing to undo (the server runs MoveL again).
    startMs := -1;
    cruiseEndMs := -1;
    endMs := -1;
  ENDPROC

  PROC spherecal_line_move(robtarget target, speeddata speed)
    ! The server's MoveL, stamped: the trap stamps the path's passing
    ! stampDist from its start, and stampDist before its end.
    startMs := -1;
    cruiseEndMs := -1;
    endMs := -1;
    TriggInt startTrigg, stampDist \Start, startInt;
    TriggInt cruiseEndTrigg, stampDist, cruiseEndInt;
    TriggL target, speed, startTrigg \T2:=cruiseEndTrigg, fine,
      tool0 \WObj:=wobj0;
    WaitTime \InPos, 0;
    endMs := ClockMs();
    Incr moves;
  ENDPROC

  PROC spherecal_line_stamps(INOUT num n, INOUT num tStart,
      INOUT num tCruiseEnd, INOUT num tEnd)
    ! The moves stamped since LSTART and the last one's stamps, ms.
    n := moves;
    tStart := startMs;
    tCruiseEnd := cruiseEndMs;
    tEnd := endMs;
  ENDPROC

  LOCAL FUNC num ClockMs()
    RETURN Round(ClkRead(lineClock) * 1000);
  ENDFUNC

  LOCAL TRAP StartTrap
    startMs := ClockMs();
  ENDTRAP

  LOCAL TRAP CruiseEndTrap
    cruiseEndMs := ClockMs();
  ENDTRAP
ENDMODULE
