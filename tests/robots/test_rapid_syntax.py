"""The offline RAPID syntax check, run on every RAPID module the project ships or writes:
the server modules, every RAPID module the exports write (found through the export
function, whatever it names its files), and the RAPID examples of the docs.

Two checks: the project's own structural check (spherecal.robots.abb_irb2400.rapid_syntax:
blocks, declarations, semicolons, string lengths, known names) and rapidchecker's grammar
(a test dependency), which parses expressions and arguments more strictly but lacks three
rules that correct RAPID needs (see _for_rapidchecker). Each check is shown to fail on
broken modules.
"""

from __future__ import annotations

import re
import textwrap
from importlib import resources
from pathlib import Path

import pytest

from spherecal.robots.abb_irb2400.rapid_syntax import check_module, check_modules, main, tokenize
from reference_sensor import reference_fov

RAPID_DIR = resources.files("spherecal.robots.abb_irb2400") / "rapid"
CORE = (RAPID_DIR / "SpherecalServer.mod").read_text()
LINKS = {name: (RAPID_DIR / name).read_text() for name in ("SpherecalSerial.mod", "SpherecalSocket.mod")}
EGM = (RAPID_DIR / "SpherecalEgm.mod").read_text()
DOCS = Path(__file__).resolve().parents[2] / "docs"


@pytest.fixture(scope="module")
def exported_modules(tmp_path_factory):
    """{file name: text} of every RAPID module (.mod, .sys) the exports of an IRB 2400 run
    write (its plugin's and the core's exporters, with their default settings), for a
    result of each mounting mode."""
    from spherecal.estimation import solve
    from spherecal.io.exporters import write_exports
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    host = PluginHost()
    found = {}
    for mounting in ("eye_in_hand", "eye_to_hand"):
        result = solve(simulate_dataset(standard_cell(mounting, seed=4, fov=reference_fov()),
                                        SweepPlan(profiles_per_station=6))).result
        plan = host.export_plan(None, mounting, "abb_irb2400")
        paths = write_exports(result, tmp_path_factory.mktemp(mounting), plan)
        rapid = [p for p in paths.values() if p.suffix.lower() in (".mod", ".sys")]
        assert rapid, f"the {mounting} exports wrote no RAPID module: {sorted(paths)}"
        found.update({f"{mounting}/{p.name}": p.read_text() for p in rapid})
    return found


def _doc_modules() -> dict[str, str]:
    """Every MODULE ... ENDMODULE example in docs/*.md (fenced or indented)."""
    found = {}
    for doc in sorted(DOCS.glob("*.md")):
        for n, m in enumerate(re.finditer(r"^([ \t]*)MODULE \w+.*?^\1ENDMODULE[ \t]*$", doc.read_text(),
                                          re.M | re.S)):
            found[f"{doc.name}#{n + 1}"] = textwrap.dedent(m[0])
    return found


# --- what ships passes -------------------------------------------------------------------------
@pytest.mark.parametrize("link", sorted(LINKS))
def test_the_server_modules_pass_together(link):
    assert check_modules({"SpherecalServer.mod": CORE, link: LINKS[link]}) == {"SpherecalServer.mod": [],
                                                                                link: []}


@pytest.mark.parametrize("link", sorted(LINKS))
def test_the_pose_stream_module_passes_with_the_server(link):
    modules = {"SpherecalServer.mod": CORE, link: LINKS[link], "SpherecalEgm.mod": EGM}
    assert check_modules(modules) == {name: [] for name in modules}


def test_the_server_calls_the_pose_stream_module_by_name():
    """The server loads without SpherecalEgm.mod (a controller without the EGM option):
    it names the module's routines only in late-bound calls, which the check does not
    resolve, and the module declares both."""
    assert '%"spherecal_egm_start"% periodMs;' in CORE and '%"spherecal_egm_stop"%;' in CORE
    assert not re.search(r"^\s*spherecal_egm_", CORE, re.M)
    assert check_module(EGM, "SpherecalEgm.mod") == []
    assert {"SPHERECAL_EGM_START", "SPHERECAL_EGM_STOP"} <= set(re.findall(r"^  PROC (\w+)", EGM.upper(), re.M))


@pytest.mark.parametrize("old, new, expected", [
    ("EGMStreamStart egmId", "EGMStremStart egmId", "unknown instruction or procedure EGMStremStart"),
    ("LOCAL VAR egmident egmId;", "LOCAL VAR egmid egmId;", "unknown data type egmid"),
    ("EGM_FRAME_WOBJ, FRAME_WOBJ,", "EGM_FRAME_WOBJECT, FRAME_WOBJ,", "unknown data EGM_FRAME_WOBJECT"),
])
def test_a_broken_pose_stream_module_fails(old, new, expected):
    assert EGM.count(old) == 1
    problems = check_module(EGM.replace(old, new), "SpherecalEgm.mod")
    assert any(expected in p for p in problems), problems


def test_the_server_needs_its_link_module():
    """The server alone refers to the link routines no module declares: the check resolves
    names across the modules loaded together, and only there."""
    problems = check_module(CORE, "SpherecalServer.mod")
    assert problems and all("spherecal_link_" in p for p in problems), problems


def test_every_exported_rapid_module_passes(exported_modules):
    for name, text in exported_modules.items():
        assert check_module(text, name) == [], name


def test_the_rapid_examples_of_the_docs_pass():
    examples = _doc_modules()
    assert len(examples) >= 2, f"the docs lost their RAPID examples: {sorted(examples)}"
    for label, text in examples.items():
        modules = {label: text, "SpherecalServer.mod": CORE, "SpherecalSerial.mod": LINKS["SpherecalSerial.mod"]}
        assert check_modules(modules)[label] == [], (label, text)


def test_the_command_line_checks_files_together(tmp_path, capsys):
    for name, text in {"SpherecalServer.mod": CORE, **LINKS}.items():
        (tmp_path / name).write_text(text)
    assert main([str(tmp_path / "SpherecalServer.mod"), str(tmp_path / "SpherecalSocket.mod")]) == 0
    assert main([str(tmp_path / "SpherecalServer.mod")]) == 1
    assert "unknown instruction or procedure spherecal_link_open" in capsys.readouterr().out


# --- broken modules fail, each with its own message -------------------------------------------------
BROKEN = {
    "missing ENDIF": (
        "SpherecalServer.mod", "      ENDIF\n    ENDIF\n  ENDPROC", "      ENDIF\n  ENDPROC",
        "has no ENDIF before 'ENDPROC'"),
    "an 81-character string": (
        "SpherecalServer.mod", '"no checksum"', '"' + "x" * 81 + '"',
        "a string of 81 characters (a RAPID string holds at most 80)"),
    "a misspelt ENDWHILE": (
        "SpherecalServer.mod", "    ENDWHILE\n  ENDPROC\n\n  PROC spherecal_server_on_stop",
        "    ENDWHLE\n  ENDPROC\n\n  PROC spherecal_server_on_stop", "unknown instruction or procedure ENDWHLE"),
    "a misspelt ELSE": (
        "SpherecalSocket.mod", "      ELSE\n        ! Printable", "      ELS\n        ! Printable",
        "unknown instruction or procedure ELS"),
    "a misspelt instruction": (
        "SpherecalServer.mod", "MoveL target", "MoveLL target", "unknown instruction or procedure MoveLL"),
    "a misspelt socket instruction": (
        "SpherecalSocket.mod", "SocketReceive client", "SocketRecieve client",
        "unknown instruction or procedure SocketRecieve"),
    "a misspelt function": (
        "SpherecalServer.mod", "j := CJointT();", "j := CJointTarget();", "unknown function CJointTarget"),
    "a misspelt variable": (
        "SpherecalServer.mod", "targetReached := TRUE;", "targetReachd := TRUE;",
        "unknown data targetReachd (not declared here nor predefined)"),
    "a misspelt data type": (
        "SpherecalSerial.mod", "LOCAL VAR iodev channel;", "LOCAL VAR iodevice channel;",
        "unknown data type iodevice"),
    "a missing semicolon": (
        "SpherecalServer.mod", "    Incr nFields;", "    Incr nFields", "missing ';' after Incr"),
    "a declaration after a statement": (
        "SpherecalServer.mod", "    VAR num space;\n    nFields := 0;", "    nFields := 0;\n    VAR num space;",
        "declaration of data after a statement"),
    "a value returned from a PROC": (
        "SpherecalServer.mod", '"no checksum";\n      RETURN;', '"no checksum";\n      RETURN 1;',
        "RETURN with a value in a PROC"),
    "a FUNC returning nothing": (
        "SpherecalServer.mod", "    RETURN TRUE;", "    RETURN;", "RETURN without a value in a FUNC"),
    "a PROC closed by ENDFUNC": (
        "SpherecalSerial.mod", "    ChannelFailed \"WriteStrBin\", ERRNO;\n  ENDPROC",
        "    ChannelFailed \"WriteStrBin\", ERRNO;\n  ENDFUNC", "ends with ENDFUNC"),
    "an ENDIF too many": (
        "SpherecalServer.mod", "    ConfL \\Off;", "    ConfL \\Off;\n    ENDIF", "ENDIF without its opening"),
    "a function called as an instruction": (
        "SpherecalServer.mod", "    ConfL \\Off;", "    ConfL \\Off;\n    CJointT;",
        "unknown instruction or procedure CJointT (a function"),
    "LOCAL inside a routine": (
        "SpherecalSocket.mod", "    VAR byte b;", "    LOCAL VAR byte b;", "has no ENDPROC before 'LOCAL'"),
    "a CONST without a value": (
        "SpherecalSocket.mod", "LOCAL CONST byte CR := 13;", "LOCAL CONST byte CR;", "CONST CR has no value"),
    "an unclosed bracket": (
        "SpherecalServer.mod", "IF NOT StrToVal(seqText, seq) THEN", "IF NOT StrToVal(seqText, seq THEN",
        "expected ')' after the arguments of StrToVal"),
    "a missing ENDMODULE": ("SpherecalSerial.mod", "  ENDPROC\nENDMODULE", "  ENDPROC\n", "has no ENDMODULE"),
    "a name of 33 characters": (
        "SpherecalSocket.mod", "LOCAL VAR num rxNext := 1;", "LOCAL VAR num " + "r" * 33 + " := 1;",
        "more than 32 characters"),
}


def _modules_with(module: str, text: str) -> dict[str, str]:
    link = module if module in LINKS else "SpherecalSerial.mod"
    modules = {"SpherecalServer.mod": CORE, link: LINKS[link]}
    modules[module] = text
    return modules


@pytest.mark.parametrize("fault", sorted(BROKEN))
def test_a_broken_server_module_fails(fault):
    module, old, new, expected = BROKEN[fault]
    text = {"SpherecalServer.mod": CORE, **LINKS}[module]
    assert text.count(old) == 1, f"the fault {fault!r} no longer matches {module}"
    broken = text.replace(old, new)
    problems = check_modules(_modules_with(module, broken))[module]
    assert any(expected in p for p in problems), problems
    assert all(re.match(r"line \d+: ", p) for p in problems)


@pytest.mark.parametrize("fault, old, new, expected", [
    ("a missing semicolon", "0, 0, 0]];", "0, 0, 0]]", "missing ';'"),
    ("a misspelt data type", "PERS tooldata ", "PERS tooldat ", "unknown data type tooldat"),
    ("a misspelt keyword", "ENDMODULE", "ENDMODUL", "has no ENDMODULE"),
])
def test_a_broken_exported_module_fails(exported_modules, fault, old, new, expected):
    text = exported_modules["eye_in_hand/SpherecalSensor.mod"]
    assert text.count(old) == 1
    assert any(expected in p for p in check_module(text.replace(old, new))), fault


def test_string_lengths_count_characters_not_escapes():
    """A RAPID string's length counts "" and \\hh as one character each."""
    problems: list[str] = []
    tokenize('s := "' + 'a' * 78 + '\\0A""";', problems)  # 78 + LF + quote = 80
    assert problems == []
    tokenize('s := "' + 'a' * 79 + '\\0A""";', problems)
    assert problems == ["line 1: a string of 81 characters (a RAPID string holds at most 80)"]


# --- rapidchecker's grammar, where it reaches ------------------------------------------------------
def _for_rapidchecker(text: str) -> str:
    """The module rewritten around three gaps of rapidchecker 0.1.5's grammar, each valid
    RAPID: LOCAL before PROC/FUNC, expressions as array indices (fields{i + 2}), and error
    handlers in functions. Functions are checked as procedures; index expressions become a
    plain name. Nothing else is changed; the project's own check above reads the module
    as it is."""
    text = re.sub(r"^(\s*)LOCAL (PROC|FUNC)\b", r"\1\2", text, flags=re.M)
    text = re.sub(r"^(\s*)FUNC \w+ (\w+\()", r"\1PROC \2", text, flags=re.M)
    text = re.sub(r"\bENDFUNC\b", "ENDPROC", text)
    return re.sub(r"\{([^{}]*[^\w{}][^{}]*)\}", "{index}", text)


@pytest.fixture(scope="module")
def rapidchecker():
    from rapidchecker import check
    from rapidchecker.config import CONFIG, Config

    assert CONFIG == Config(), "a rapidchecker.toml in the working directory changed rapidchecker's rules"
    return check


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # rapidchecker calls old pyparsing names
def test_rapidchecker_parses_every_module(rapidchecker, exported_modules):
    for name, text in {"SpherecalServer.mod": CORE, **LINKS, "SpherecalEgm.mod": EGM, **exported_modules}.items():
        assert [str(e) for e in rapidchecker.check_format(_for_rapidchecker(text))] == [], name


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_rapidchecker_fails_a_broken_module(rapidchecker):
    broken = LINKS["SpherecalSocket.mod"].replace("        got := TRUE;\n      ELSE", "        got := TRUE\n      ELSE")
    errors = [str(e) for e in rapidchecker.check_format(_for_rapidchecker(broken))]
    assert len(errors) == 1 and "Expected ';'" in errors[0], errors
