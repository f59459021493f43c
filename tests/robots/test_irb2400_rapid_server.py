"""Offline safety checks of the RAPID server modules: SpherecalServer.mod (the protocol),
its two link modules, SpherecalSerial.mod and SpherecalSocket.mod, and its pose stream
modules, SpherecalEgm.mod and SpherecalLine.mod.

Nothing here runs RAPID: a small checker reads each module's text and enforces the rules
that keep the server from moving the arm unasked or hiding faults (see "How the server
behaves" in docs/robot-abb-irb2400.md). The syntax of the modules is checked in
tests/robots/test_rapid_syntax.py.

* no ``TRYNEXT`` or ``RETRY`` in the error handler of a routine that moves (one with a
  move instruction, or that calls such a routine of the module): either would run a move
  again without a request, as a ``TRYNEXT`` in ``main`` does after a ``ReadStr`` timeout;
* every read from a channel or socket, and every accept, has ``\\Time`` (without it
  ``ReadStr`` gives up after 60 s);
* the variable a read assigns (``ReadStr``, or the line the server hands to
  ``spherecal_link_read``) is cleared by the statement just before the read;
* no ``SkipWarn`` (errors stay in the event log), and every error handler looks at
  ``ERRNO`` (errors are handled one by one);
* every top-level data and routine declaration is ``LOCAL`` except the documented entry
  points and link routines, which carry the ``spherecal_`` prefix; no ``PROC main``;
* lines of at most 80 characters, identifiers of at most 32.

Each rule is shown to fire on a copy of the module with one fault put back in, and on
an excerpt of the server as it was before these rules.
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass, field
from importlib import resources

import pytest

RAPID_DIR = resources.files("spherecal.robots.abb_irb2400") / "rapid"
#: The server's modules and the only global names each may declare.
MODULES = {
    "SpherecalServer.mod": frozenset({"spherecal_server_main", "spherecal_server_on_stop"}),
    "SpherecalSerial.mod": frozenset({"spherecal_link_open", "spherecal_link_read", "spherecal_link_write",
                                      "spherecal_link_session"}),
    "SpherecalSocket.mod": frozenset({"spherecal_link_open", "spherecal_link_read", "spherecal_link_write",
                                      "spherecal_link_session"}),
    "SpherecalEgm.mod": frozenset({"spherecal_egm_start", "spherecal_egm_stop"}),
    "SpherecalLine.mod": frozenset({"spherecal_line_start", "spherecal_line_stop", "spherecal_line_move",
                                    "spherecal_line_stamps"}),
}
TEXTS = {name: (RAPID_DIR / name).read_text() for name in MODULES}
MODULE_TEXT = TEXTS["SpherecalServer.mod"]
PUBLIC_ROUTINES = MODULES["SpherecalServer.mod"]

_MOVE = re.compile(r"\b(Move(?:L|J|C|AbsJ|ExtJ)\w*|Search(?:L|C|ExtJ)\w*|Trigg(?:L|J|C)(?:IOs)?|Arc[LC]\w*)\b")
_READ = re.compile(r"\b(ReadStr|ReadStrBin|ReadNum|ReadBin|ReadAnyBin|ReadRawBytes|SocketReceive|SocketAccept"
                   r"|spherecal_link_read)\b")
#: Reads whose first argument (or result) is the line read, which must be cleared first.
_STRING_READS = {"ReadStr", "ReadStrBin", "spherecal_link_read"}
#: Reads that wait through the link module (which has its own \Time).
_LINK_READS = {"spherecal_link_read"}
_DATA = re.compile(r"^\s*(LOCAL\s+|TASK\s+)?(VAR|CONST|PERS)\s+\w+\s+(\w+)", re.I)
_ROUTINE = re.compile(r"^\s*(LOCAL\s+)?(PROC|FUNC\s+\w+|TRAP)\s+(\w+)", re.I)
_ROUTINE_END = re.compile(r"^\s*END(PROC|FUNC|TRAP)\b", re.I)
_SECTION = re.compile(r"^\s*(ERROR|BACKWARD|UNDO)\s*$", re.I)


@dataclass
class Routine:
    name: str
    local: bool
    body: str = ""  #: code before the ERROR (or BACKWARD/UNDO) section
    handler: str = ""  #: code of the ERROR section
    has_handler: bool = False
    calls: set[str] = field(default_factory=set)


def _code(text: str) -> list[str]:
    """The module's lines without comments; every string literal becomes "" (empty) or
    "_" (not empty), so that nothing inside a string is read as code."""
    out = []
    for raw in text.splitlines():
        line, i, in_str, buf = raw, 0, False, []
        while i < len(line):
            c = line[i]
            if in_str:
                if c == '"':
                    if i + 1 < len(line) and line[i + 1] == '"':  # "" inside a string
                        buf_str.append(c)
                        i += 2
                        continue
                    buf.append('""' if not buf_str else '"_"')
                    in_str = False
                else:
                    buf_str.append(c)
            elif c == '"':
                in_str, buf_str = True, []
            elif c == "!":
                break
            else:
                buf.append(c)
            i += 1
        out.append("".join(buf).rstrip())
    return out


def parse(text: str) -> tuple[list[tuple[str, str, bool]], dict[str, Routine]]:
    """(top-level declarations as (kind, name, local), routines by name)."""
    decls: list[tuple[str, str, bool]] = []
    routines: dict[str, Routine] = {}
    current: Routine | None = None
    section = "body"
    for line in _code(text):
        if current is None:
            if m := _ROUTINE.match(line):
                current = Routine(m[3], bool(m[1]))
                section = "body"
                decls.append((m[2].split()[0].upper(), m[3], bool(m[1])))
            elif m := _DATA.match(line):
                decls.append((m[2].upper(), m[3], (m[1] or "").strip().upper() == "LOCAL"))
            continue
        if _ROUTINE_END.match(line):
            routines[current.name] = current
            current = None
        elif m := _SECTION.match(line):
            section = m[1].upper()
            current.has_handler |= section == "ERROR"
        elif section == "body":
            current.body += line + "\n"
        elif section == "ERROR":
            current.handler += line + "\n"
    for r in routines.values():
        words = set(re.findall(r"\w+", r.body + r.handler))
        r.calls = {name for name in routines if name in words and name != r.name}
    return decls, routines


def moving_routines(routines: dict[str, Routine]) -> set[str]:
    """Routines with a move instruction, and every routine that calls one of them."""
    moving = {n for n, r in routines.items() if _MOVE.search(r.body + r.handler)}
    while True:
        more = {n for n, r in routines.items() if r.calls & moving} - moving
        if not more:
            return moving
        moving |= more


def _call_args(code: str, start: int) -> str:
    """The arguments of a call whose name ends at ``start``: balanced parentheses for a
    function, up to the ';' for an instruction."""
    rest = code[start:].lstrip()
    if not rest.startswith("("):
        return rest.split(";", 1)[0]
    depth = 0
    for i, c in enumerate(rest):
        depth += c == "("
        depth -= c == ")"
        if depth == 0:
            return rest[1:i]
    return rest


def check_rapid_server(text: str, public: frozenset[str] = PUBLIC_ROUTINES) -> list[str]:
    """Every broken rule of a module whose global names may be ``public``, as one line
    each; [] when the module passes."""
    problems: list[str] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        if len(raw) > 80:
            problems.append(f"line {n} has {len(raw)} characters (at most 80)")
    decls, routines = parse(text)
    for kind, name, local in decls:
        if len(name) > 32:
            problems.append(f"{kind} {name}: more than 32 characters")
        if name.lower() == "main":
            problems.append(f"{kind} main: the module must not declare main (it would clash with the user's)")
        if not local and name not in public:
            problems.append(f"{kind} {name} is not LOCAL")
        if not local and not (kind in {"PROC", "FUNC", "TRAP"} and name.startswith("spherecal_")):
            problems.append(f"{kind} {name}: a global name must be a routine named spherecal_...")
    moving = moving_routines(routines)
    for name, r in routines.items():
        code = r.body + r.handler
        if re.search(r"\bSkipWarn\b", code, re.I):
            problems.append(f"{name}: SkipWarn hides the error from the event log")
        if r.has_handler and not re.search(r"\bERRNO\b", r.handler):
            problems.append(f"{name}: the error handler does not look at ERRNO")
        if name in moving:
            for word in ("TRYNEXT", "RETRY"):
                if re.search(rf"\b{word}\b", r.handler, re.I):
                    problems.append(f"{name}: {word} in the error handler of a routine that moves")
        for m in _READ.finditer(code):
            if m.start() and code[m.start() - 1] == "\\":  # an argument's name (\RawData), not a read
                continue
            if name == m[1]:  # the declaration of the link read itself
                continue
            args = _call_args(code, m.end())
            if m[1] not in _LINK_READS and not re.search(r"\\Time\b", args):
                problems.append(f"{name}: {m[1]} without \\Time (it gives up after 60 s)")
            if m[1] in _STRING_READS:
                before = code[: m.start()]
                if m[1] in _LINK_READS:  # the line is the first argument: read as "line := <read>"
                    first = re.match(r"\s*([\w{}.]+)", args)
                    before += (first[1] + " := ") if first else ""
                target = re.search(r"([\w{}.]+)\s*:=\s*$", before)
                if target is None:
                    problems.append(f"{name}: the result of {m[1]} must be assigned to a variable")
                    continue
                var = re.escape(target[1])
                if not re.search(rf'(?:^|[;\s]){var}\s*:=\s*""\s*;\s*$', before[: target.start()]):
                    problems.append(f"{name}: {target[1]} is not cleared just before {m[1]}")
    return problems


# --- the shipped modules -----------------------------------------------------------------------
@pytest.mark.parametrize("module", sorted(MODULES))
def test_the_rapid_server_passes_the_safety_checks(module):
    assert check_rapid_server(TEXTS[module], MODULES[module]) == []


def test_the_checker_sees_the_server_structure():
    """Guards the checker itself: it must find the routines, the moves and the reads."""
    decls, routines = parse(MODULE_TEXT)
    assert {"spherecal_server_main", "Serve", "MoveToTarget", "ReadRequest", "Reachable"} <= set(routines)
    moving = moving_routines(routines)
    assert {"MoveToTarget", "Serve", "spherecal_server_main"} <= moving
    assert "ReadRequest" not in moving and "Checksum" not in moving
    assert sum(kind in {"VAR", "CONST"} for kind, _, _ in decls) > 10
    assert [name for _, name, local in decls if not local] == ["spherecal_server_main", "spherecal_server_on_stop"]
    assert 'line := "";\n    spherecal_link_read line, haveLine;' in MODULE_TEXT
    assert "ReadStr(channel \\Time:=WAIT_MAX)" in TEXTS["SpherecalSerial.mod"]
    socket = TEXTS["SpherecalSocket.mod"]
    assert "SocketReceive client \\RawData:=rx \\Time:=WAIT_MAX;" in socket
    assert "\\Time:=WAIT_MAX;" in socket.split("SocketAccept", 1)[1].split("\n", 1)[0]
    for name in ("SpherecalSerial.mod", "SpherecalSocket.mod"):  # the links move nothing
        assert moving_routines(parse(TEXTS[name])[1]) == set()


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_error_handler_in_the_modules_runs_anything_again(module):
    """Stronger than the rule: no RETRY or TRYNEXT anywhere in the modules' code."""
    code = "\n".join(_code(TEXTS[module]))
    assert not re.search(r"\b(RETRY|TRYNEXT)\b", code)


# one fault put back into a shipped module -> the problem the checker must report
MUTATIONS = {
    "serial read without \\Time": (
        "SpherecalSerial.mod", "ReadStr(channel \\Time:=WAIT_MAX)", "ReadStr(channel)",
        "spherecal_link_read: ReadStr without \\Time"),
    "socket read without \\Time": (
        "SpherecalSocket.mod", "SocketReceive client \\RawData:=rx \\Time:=WAIT_MAX;",
        "SocketReceive client \\RawData:=rx;", "spherecal_link_read: SocketReceive without \\Time"),
    "socket accept without \\Time": (
        "SpherecalSocket.mod", " \\ClientAddress:=peer \\Time:=WAIT_MAX;", " \\ClientAddress:=peer;",
        "Accept: SocketAccept without \\Time"),
    "serial line not cleared before the read": (
        "SpherecalSerial.mod", '    text := "";\n    text := ReadStr', "    text := ReadStr",
        "spherecal_link_read: text is not cleared just before ReadStr"),
    "server line not cleared before the read": (
        "SpherecalServer.mod", '    line := "";\n    spherecal_link_read', "    spherecal_link_read",
        "ReadRequest: line is not cleared just before spherecal_link_read"),
    "RETRY after a failed move": (
        "SpherecalServer.mod",
        "    ReplyError seqText, E_MOTION, \"motion error \" + NumToStr(ERRNO, 0);\n    RETURN;",
        "    RETRY;", "MoveToTarget: RETRY in the error handler of a routine that moves"),
    "TRYNEXT in a routine that calls a move": (
        "SpherecalServer.mod",
        "    ReplyError seqText, E_SYNTAX, \"request failed, error \"\n      + NumToStr(ERRNO, 0);\n    RETURN;",
        "    TRYNEXT;", "Serve: TRYNEXT in the error handler of a routine that moves"),
    "SkipWarn": (
        "SpherecalServer.mod", "    CASE ERR_ROBLIMIT:\n", "    CASE ERR_ROBLIMIT:\n      SkipWarn;\n",
        "Reachable: SkipWarn hides the error from the event log"),
    "a global variable": (
        "SpherecalServer.mod", "  LOCAL VAR robtarget target;", "  VAR robtarget target;",
        "VAR target is not LOCAL"),
    "a global link variable": (
        "SpherecalSocket.mod", "  LOCAL VAR socketdev client;", "  VAR socketdev client;",
        "VAR client is not LOCAL"),
    "a global helper routine": (
        "SpherecalServer.mod", "  LOCAL PROC Reply(", "  PROC Reply(", "PROC Reply is not LOCAL"),
    "PROC main": (
        "SpherecalServer.mod", "  PROC spherecal_server_main()", "  PROC main()",
        "PROC main: the module must not declare main (it would clash with the user's)"),
    "a catch-all handler": (
        "SpherecalServer.mod", "    TEST ERRNO\n    CASE ERR_ROBLIMIT:", "    TEST 0\n    CASE 0:",
        "Reachable: the error handler does not look at ERRNO"),
    "a long line": (
        "SpherecalServer.mod", "  LOCAL CONST num E_MOTION := 6;",
        "  LOCAL CONST num E_MOTION := 6;" + " " * 60 + "! x", "characters (at most 80)"),
}


@pytest.mark.parametrize("fault", sorted(MUTATIONS))
def test_each_rule_fires_on_its_fault(fault):
    module, old, new, expected = MUTATIONS[fault]
    text = TEXTS[module]
    assert text.count(old) == 1, f"the mutation for {fault!r} no longer matches {module}"
    problems = check_rapid_server(text.replace(old, new), MODULES[module])
    assert any(expected in p for p in problems), problems


# The parts of the server as it was before these rules (spherecal 0.1), shortened.
OLD_SERVER = """MODULE SpherecalServer
  VAR iodev channel;
  VAR robtarget target;

  PROC main()
    VAR string line;
    Open "com1:", channel \\Bin;
    WHILE TRUE DO
      line := ReadStr(channel \\RemoveCR);
      Serve line;
    ENDWHILE
  ERROR
    ! A channel error: skip it and keep serving.
    TRYNEXT;
  ENDPROC

  PROC Serve(string line)
    MoveToTarget;
  ENDPROC

  PROC MoveToTarget()
    MoveL target, v100, fine, tool0 \\WObj:=wobj0;
  ERROR
    SkipWarn;
    RETURN;
  ENDPROC
ENDMODULE
"""


def test_the_checker_rejects_the_old_server():
    problems = check_rapid_server(OLD_SERVER)
    for expected in [
        "PROC main: the module must not declare main",
        "VAR channel is not LOCAL",
        "PROC Serve is not LOCAL",
        "main: ReadStr without \\Time",
        "main: line is not cleared just before ReadStr",
        "main: TRYNEXT in the error handler of a routine that moves",
        "main: the error handler does not look at ERRNO",
        "MoveToTarget: SkipWarn hides the error",
    ]:
        assert any(expected in p for p in problems), (expected, problems)


# --- the loading instructions of the docs ------------------------------------------------------
def test_the_docs_load_the_server_with_valid_names():
    """The RAPID the docs give for loading calls the module's public, parameterless entry
    routine by its plain name (``SpherecalServer:main`` is not RAPID)."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "robot-abb-irb2400.md").read_text()
    assert "SpherecalServer:main" not in doc
    snippet = re.search(r"^( +)MODULE MainModule\n(.*?)^\1ENDMODULE\n", doc, re.M | re.S)
    assert snippet, "the docs lost their MainModule example"
    decls, routines = parse(textwrap.dedent(snippet[0]))
    assert [name for _, name, _ in decls] == ["main"]
    calls = re.findall(r"^\s*(\w+);", routines["main"].body, re.M)
    assert calls == ["spherecal_server_main"]
    assert re.search(r"^  PROC spherecal_server_main\(\)$", MODULE_TEXT, re.M)  # global, no parameters
    for name in PUBLIC_ROUTINES:
        assert f"`{name}`" in doc
