"""An offline structural check of RAPID program modules, run by the test suite on the
RAPID server modules this plugin ships and on every RAPID module the exports write.

Nothing here runs RAPID or knows every rule of the language; it reads a module the way
the controller's loader starts to, and reports, with the line:

* blocks that do not close, or close with the wrong word: ``MODULE``/``ENDMODULE``,
  ``PROC``/``FUNC``/``TRAP`` and their ``END``, ``IF``/``ELSEIF``/``ELSE``/``ENDIF``,
  ``WHILE``, ``FOR``, ``TEST``/``CASE``/``DEFAULT``, ``RECORD``; an ``END...`` with nothing
  to close;
* declarations after the first statement of a routine, ``LOCAL`` inside a routine, a
  ``CONST`` without a value, a name declared twice, names longer than 32 characters;
* a missing ``;`` after a declaration or a simple statement;
* string literals of more than 80 characters (a RAPID string holds 80);
* instructions, functions, data types and data that are neither declared in the modules
  checked together nor known RAPID names (:mod:`.rapid_names`, from the public RAPID
  reference manual): a misspelt instruction or keyword is caught here;
* ``RETURN`` with a value in a procedure or without one in a function; a function used as
  an instruction, or an instruction as a function;
* expressions and argument lists that do not parse (operands, operators, brackets,
  ``\\Switch``, ``\\Opt:=value`` and ``name:=value`` arguments).

Modules checked together (:func:`check_modules`) see each other's global (not ``LOCAL``)
routines and data, as modules loaded into one task do.

Command line: ``python -m spherecal.robots.abb_irb2400.rapid_syntax FILE.mod ...``
checks the files together; exit status 1 when any problem is found.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from . import rapid_names as N

#: Longest RAPID string, characters.
MAX_STRING = 80
#: Longest RAPID identifier, characters.
MAX_NAME = 32

_BINARY = {"+", "-", "*", "/", "<", ">", "=", "<=", ">=", "<>", "DIV", "MOD", "AND", "OR", "XOR"}
#: Words that end any statement list (they cannot start a statement).
_HARD_STOPS = {"ENDPROC", "ENDFUNC", "ENDTRAP", "ENDMODULE", "PROC", "FUNC", "TRAP", "ERROR", "UNDO",
               "BACKWARD", "LOCAL", "RECORD", "ENDRECORD"}
_BLOCK_ENDS = {"ENDIF", "ENDWHILE", "ENDFOR", "ENDTEST", "ELSE", "ELSEIF", "CASE", "DEFAULT"}
_DECL = {"VAR", "PERS", "CONST"}


@dataclass(frozen=True)
class Token:
    kind: str  #: "name", "word" (a reserved word), "num", "str", "op" or "eof"
    text: str
    line: int

    @property
    def up(self) -> str:
        return self.text.upper()


def tokenize(text: str, problems: list[str]) -> list[Token]:
    """The tokens of ``text`` (comments dropped); string problems go to ``problems``."""
    tokens: list[Token] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        i = 0
        while i < len(raw):
            c = raw[i]
            if c in " \t\r\f\v":
                i += 1
            elif c == "!":
                break
            elif c == '"':
                j, chars, closed = i + 1, 0, False
                while j < len(raw):
                    if raw[j] == '"':
                        if j + 1 < len(raw) and raw[j + 1] == '"':  # "" is one quote
                            j, chars = j + 2, chars + 1
                            continue
                        closed = True
                        break
                    if raw[j] == "\\":
                        if raw[j + 1: j + 2] == "\\":
                            j += 2
                        elif re.match(r"[0-9A-Fa-f]{2}", raw[j + 1: j + 3]):
                            j += 3
                        else:
                            problems.append(f"line {n}: a backslash in a string must be \\\\ or \\ and two hex digits")
                            j += 1
                        chars += 1
                        continue
                    j, chars = j + 1, chars + 1
                if not closed:
                    problems.append(f"line {n}: a string is not closed on its line")
                    break
                if chars > MAX_STRING:
                    problems.append(f"line {n}: a string of {chars} characters (a RAPID string holds at most "
                                    f"{MAX_STRING})")
                tokens.append(Token("str", raw[i: j + 1], n))
                i = j + 1
            elif c.isalpha():
                m = re.match(r"[A-Za-z][A-Za-z0-9_]*", raw[i:])
                word = m[0]
                tokens.append(Token("word" if word.upper() in N.RESERVED else "name", word, n))
                i += len(word)
            elif c.isdigit() or (c == "." and raw[i + 1: i + 2].isdigit()):
                m = re.match(r"0[xX][0-9A-Fa-f]+|(\d+\.?\d*|\.\d+)([Ee][+-]?\d+)?", raw[i:])
                tokens.append(Token("num", m[0], n))
                i += len(m[0])
            else:
                two = raw[i: i + 2]
                if two in (":=", "<>", "<=", ">="):
                    tokens.append(Token("op", two, n))
                    i += 2
                elif c in "+-*/<>=()[]{},;:\\.%|":
                    tokens.append(Token("op", c, n))
                    i += 1
                else:
                    problems.append(f"line {n}: unexpected character {c!r}")
                    i += 1
    last = tokens[-1].line if tokens else 1
    tokens.append(Token("eof", "end of file", last))
    return tokens


@dataclass
class _Ref:
    kind: str  #: "instruction", "function", "data" or "type"
    name: str  #: upper case
    text: str  #: as written
    line: int
    scope: frozenset[str]  #: names local to the routine at the point of use


@dataclass
class RapidModule:
    """What :func:`parse_module` found in one module."""

    label: str
    name: str = ""
    routines: dict[str, tuple[str, bool]] = field(default_factory=dict)  #: NAME -> (kind, local)
    data: dict[str, bool] = field(default_factory=dict)  #: NAME -> local
    types: set[str] = field(default_factory=set)  #: RECORD and ALIAS names (upper case)
    global_names: list[str] = field(default_factory=list)  #: declared names that are not LOCAL, as written
    problems: list[str] = field(default_factory=list)
    refs: list[_Ref] = field(default_factory=list)


class _Parser:
    def __init__(self, text: str, label: str):
        self.mod = RapidModule(label)
        self.toks = tokenize(text, self.mod.problems)
        self.i = 0
        self.scope: set[str] = set()
        self.routine_kind = ""

    # tokens -------------------------------------------------------------------------
    @property
    def tok(self) -> Token:
        return self.toks[self.i]

    def peek(self, k: int = 1) -> Token:
        return self.toks[min(self.i + k, len(self.toks) - 1)]

    def take(self) -> Token:
        t = self.tok
        if t.kind != "eof":
            self.i += 1
        return t

    def at(self, *words: str) -> bool:
        return self.tok.kind in ("word", "op") and self.tok.up in words

    def problem(self, message: str, line: int | None = None) -> None:
        self.mod.problems.append(f"line {self.tok.line if line is None else line}: {message}")

    def expect(self, text: str, after: str) -> bool:
        if self.at(text):
            self.take()
            return True
        self.problem(f"expected '{text}' after {after}, found {self.tok.text!r}")
        return False

    def name(self, what: str) -> Token | None:
        t = self.tok
        if t.kind == "name":
            self.take()
            if len(t.text) > MAX_NAME:
                self.problem(f"{what} {t.text}: more than {MAX_NAME} characters", t.line)
            return t
        reason = " (a reserved word)" if t.kind == "word" else ""
        self.problem(f"expected {what}, found {t.text!r}{reason}")
        return None

    def skip_to_semicolon(self) -> None:
        while not self.at(";") and self.tok.kind != "eof" and not self.at(*_HARD_STOPS):
            self.take()
        if self.at(";"):
            self.take()

    def ref(self, kind: str, tok: Token) -> None:
        self.mod.refs.append(_Ref(kind, tok.up, tok.text, tok.line, frozenset(self.scope)))

    # module ---------------------------------------------------------------------------
    def module(self) -> RapidModule:
        if not self.at("MODULE"):
            self.problem(f"a module starts with MODULE, found {self.tok.text!r}")
            return self.mod
        start = self.take().line
        t = self.name("a module name")
        self.mod.name = t.text if t else ""
        if self.at("("):
            self.take()
            while self.tok.kind == "word" or self.tok.kind == "name":
                if self.tok.up not in {"SYSMODULE", "NOSTEPIN", "VIEWONLY", "READONLY", "NOVIEW"}:
                    self.problem(f"unknown module attribute {self.tok.text!r}")
                self.take()
                if not self.at(","):
                    break
                self.take()
            self.expect(")", "the module attributes")
        while not self.at("ENDMODULE") and self.tok.kind != "eof":
            local = False
            first = self.tok
            if self.at("LOCAL", "TASK"):
                local = self.take().up == "LOCAL"
            if self.at(*_DECL):
                self.declaration(module_level=True, local=local, task=first.up == "TASK")
            elif self.at("PROC", "FUNC", "TRAP"):
                if first.up == "TASK":
                    self.problem("TASK goes with data, not with a routine")
                self.routine(local)
            elif self.at("RECORD"):
                self.record()
            elif self.at("ALIAS"):
                self.take()
                self.type_ref()
                t = self.name("an alias name")
                if t:
                    self.mod.types.add(t.up)
                self.expect(";", "the ALIAS declaration")
            else:
                self.problem(f"expected a declaration or a routine, found {self.tok.text!r}")
                self.take()
                self.skip_to_semicolon()
        if not self.at("ENDMODULE"):
            self.problem(f"MODULE (line {start}) has no ENDMODULE")
            return self.mod
        self.take()
        if self.tok.kind != "eof":
            self.problem(f"text after ENDMODULE: {self.tok.text!r}")
        return self.mod

    def declare(self, tok: Token, kind: str, local: bool, module_level: bool) -> None:
        if not module_level:
            if tok.up in self.scope:
                self.problem(f"{tok.text} is declared twice in this routine", tok.line)
            self.scope.add(tok.up)
            return
        if tok.up in self.mod.data or tok.up in self.mod.routines:
            self.problem(f"{tok.text} is declared twice in the module", tok.line)
        if kind == "data":
            self.mod.data[tok.up] = local
        if not local:
            self.mod.global_names.append(tok.text)

    def type_ref(self) -> None:
        t = self.name("a data type")
        if t:
            self.ref("type", t)

    def declaration(self, module_level: bool, local: bool = False, task: bool = False) -> None:
        start = self.tok.line
        kind = self.take().up  # VAR, PERS or CONST
        self.type_ref()
        t = self.name("a data name")
        if t:
            self.declare(t, "data", local or task, module_level)
        if self.at("{"):
            self.take()
            self.expr_list()
            self.expect("}", "the array size")
        if self.at(":="):
            self.take()
            self.expr()
        elif kind == "CONST":
            self.problem(f"CONST {t.text if t else ''} has no value")
        self.end_statement(f"the declaration of {t.text if t else 'data'}", start)

    def record(self) -> None:
        start = self.take().line
        t = self.name("a record name")
        if t:
            self.mod.types.add(t.up)
        while not self.at("ENDRECORD") and self.tok.kind != "eof" and not self.at("ENDMODULE", "PROC", "FUNC"):
            self.type_ref()
            self.name("a record component")
            self.expect(";", "the record component")
        if not self.expect("ENDRECORD", f"RECORD (line {start})"):
            return

    # routines -----------------------------------------------------------------------------
    def routine(self, local: bool) -> None:
        start = self.tok.line
        kind = self.take().up
        if kind == "FUNC":
            self.type_ref()
        t = self.name(f"a {kind} name")
        if t:
            if t.up in self.mod.routines or t.up in self.mod.data:
                self.problem(f"{t.text} is declared twice in the module", t.line)
            self.mod.routines[t.up] = (kind, local)
            if not local:
                self.mod.global_names.append(t.text)
        self.scope, self.routine_kind = set(), kind
        if kind != "TRAP":
            if self.expect("(", f"{kind} {t.text if t else ''}"):
                self.parameters()
                self.expect(")", "the parameters")
        self.statements(set(), decls=True)
        for section in ("BACKWARD", "ERROR", "UNDO"):
            if self.at(section):
                self.take()
                if section == "ERROR" and self.at("("):
                    self.take()
                    while not self.at(")") and self.tok.kind != "eof":
                        self.take()
                    self.expect(")", "the ERROR numbers")
                self.statements(set())
        end = "END" + kind
        if self.at(end):
            self.take()
        elif self.at("ENDPROC", "ENDFUNC", "ENDTRAP"):
            self.problem(f"{kind} {t.text if t else ''} (line {start}) ends with {self.take().text}")
        else:
            self.problem(f"{kind} {t.text if t else ''} (line {start}) has no {end} before {self.tok.text!r}")
        self.scope, self.routine_kind = set(), ""

    def parameters(self) -> None:
        if self.at(")"):
            return
        while True:
            if self.at("\\"):
                self.take()
            while True:
                if self.at("VAR", "PERS", "INOUT"):
                    self.take()
                self.type_ref()
                t = self.name("a parameter name")
                if t:
                    self.scope.add(t.up)
                if self.at("{"):
                    while not self.at("}") and self.tok.kind != "eof":
                        self.take()
                    self.expect("}", "the array parameter")
                if not self.at("|"):
                    break
                self.take()
            if not self.at(","):
                return
            self.take()

    # statements ----------------------------------------------------------------------------
    def statements(self, stops: set[str], decls: bool = False) -> None:
        seen_statement = False
        while True:
            t = self.tok
            if t.kind == "eof" or (t.kind == "word" and (t.up in stops or t.up in _HARD_STOPS)):
                return
            if t.kind == "word" and t.up in _DECL:
                if not decls or seen_statement:
                    self.problem(f"declaration of data after a statement (in a routine, {t.text} comes first)")
                self.declaration(module_level=False)
                continue
            if t.kind == "word" and t.up in _BLOCK_ENDS:
                self.problem(f"{t.text} without its opening IF, WHILE, FOR or TEST")
                self.take()
                continue
            seen_statement = True
            self.statement()

    def close(self, word: str, opener: str, line: int) -> None:
        if self.at(word):
            self.take()
        else:
            self.problem(f"{opener} (line {line}) has no {word} before {self.tok.text!r}")

    def statement(self, simple_only: bool = False) -> None:
        t = self.tok
        up = t.up if t.kind == "word" else ""
        if simple_only and up in ("IF", "WHILE", "FOR", "TEST"):
            self.problem(f"a compact IF takes one simple statement, not {t.text}")
        if up == "IF":
            self.take()
            self.expr()
            if not self.at("THEN"):
                if simple_only:
                    return
                self.statement(simple_only=True)  # compact IF
                return
            self.take()
            self.statements({"ELSEIF", "ELSE", "ENDIF"})
            while self.at("ELSEIF"):
                self.take()
                self.expr()
                self.expect("THEN", "ELSEIF's condition")
                self.statements({"ELSEIF", "ELSE", "ENDIF"})
            if self.at("ELSE"):
                self.take()
                self.statements({"ENDIF"})
            self.close("ENDIF", "IF", t.line)
        elif up == "WHILE":
            self.take()
            self.expr()
            self.expect("DO", "WHILE's condition")
            self.statements({"ENDWHILE"})
            self.close("ENDWHILE", "WHILE", t.line)
        elif up == "FOR":
            self.take()
            v = self.name("a loop variable")
            if v:
                self.scope.add(v.up)
            self.expect("FROM", "the loop variable")
            self.expr()
            self.expect("TO", "FOR's start")
            self.expr()
            if self.at("STEP"):
                self.take()
                self.expr()
            self.expect("DO", "FOR's range")
            self.statements({"ENDFOR"})
            self.close("ENDFOR", "FOR", t.line)
        elif up == "TEST":
            self.take()
            self.expr()
            cases = 0
            while self.at("CASE"):
                self.take()
                cases += 1
                self.expr_list()
                self.expect(":", "CASE's values")
                self.statements({"CASE", "DEFAULT", "ENDTEST"})
            if self.at("DEFAULT"):
                self.take()
                self.expect(":", "DEFAULT")
                self.statements({"ENDTEST"})
            if not cases:
                self.problem(f"TEST (line {t.line}) has no CASE")
            self.close("ENDTEST", "TEST", t.line)
        elif up == "RETURN":
            self.take()
            if not self.at(";"):
                if self.routine_kind != "FUNC":
                    self.problem(f"RETURN with a value in a {self.routine_kind or 'routine'} (only a FUNC returns one)")
                self.expr()
            elif self.routine_kind == "FUNC":
                self.problem("RETURN without a value in a FUNC")
            self.end_statement("RETURN", t.line)
        elif up in ("EXIT", "RETRY", "TRYNEXT"):
            self.take()
            self.end_statement(t.text, t.line)
        elif up == "RAISE":
            self.take()
            if not self.at(";"):
                self.expr()
            self.end_statement("RAISE", t.line)
        elif up == "GOTO":
            self.take()
            self.name("a label")
            self.end_statement("GOTO", t.line)
        elif up == "CONNECT":
            self.take()
            self.data_ref()
            self.expect("WITH", "CONNECT's interrupt")
            self.name("a trap routine")
            self.end_statement("CONNECT", t.line)
        elif t.kind == "op" and t.text == "%":  # late binding: %"name"% args;
            self.take()
            self.expr()
            self.expect("%", "the late-bound routine name")
            self.arguments({";"})
            self.end_statement("the late-bound call", t.line)
        elif t.kind == "name":
            nxt = self.peek()
            if nxt.text == ":" and not simple_only:  # a label
                self.take()
                self.take()
                self.scope.add(t.up)
            elif nxt.text in (":=", "{", "."):
                self.data_ref()
                self.expect(":=", f"{t.text}")
                self.expr()
                self.end_statement(f"the assignment to {t.text}", t.line)
            else:
                self.take()
                self.ref("instruction", t)
                self.arguments({";"})
                self.end_statement(t.text, t.line)
        else:
            self.problem(f"expected a statement, found {t.text!r}")
            self.take()
            self.skip_to_semicolon()

    def end_statement(self, what: str, line: int) -> None:
        if self.at(";"):
            self.take()
        else:
            self.problem(f"missing ';' after {what} (line {line}), found {self.tok.text!r}")
            self.skip_to_semicolon()

    # expressions ---------------------------------------------------------------------------
    def expr_list(self) -> None:
        """One or more expressions separated by commas."""
        self.expr()
        while self.at(","):
            self.take()
            self.expr()

    def expr(self) -> None:
        self.unary()
        while self.tok.kind in ("op", "word") and self.tok.up in _BINARY:
            self.take()
            self.unary()

    def unary(self) -> None:
        if self.at("NOT", "-", "+"):
            self.take()
            self.unary()
        else:
            self.primary()

    def primary(self) -> None:
        t = self.tok
        if t.kind in ("num", "str") or self.at("TRUE", "FALSE"):
            self.take()
        elif self.at("("):
            self.take()
            self.expr()
            self.expect(")", "the expression in brackets")
        elif self.at("["):
            self.take()
            self.expr_list()
            self.expect("]", "the aggregate")
        elif t.kind == "name" and self.peek().text == "(":
            self.take()
            self.ref("function", t)
            self.take()
            self.arguments({")"})
            self.expect(")", f"the arguments of {t.text}")
        elif t.kind == "name":
            self.data_ref()
        else:
            self.problem(f"expected a value, found {t.text!r}")
            if t.kind != "eof" and not self.at(";"):
                self.take()

    def data_ref(self) -> None:
        t = self.name("a data name")
        if t is None:
            return
        self.ref("data", t)
        while self.at("{", "."):
            if self.take().text == "{":
                self.expr_list()
                self.expect("}", f"the index of {t.text}")
            else:
                self.name("a component name")

    def arguments(self, ends: set[str]) -> None:
        if self.at(*ends) or (self.tok.kind == "word" and self.tok.up in _HARD_STOPS | _BLOCK_ENDS):
            return
        while True:
            if self.at("\\"):
                self.take()
                self.name("an optional argument's name")
                if self.at(":="):
                    self.take()
                    self.expr()
            else:
                if self.tok.kind == "name" and self.peek().text == ":=":
                    self.take()
                    self.take()
                self.expr()
            if self.at(","):
                self.take()
            elif self.at("\\"):
                continue
            elif self.at(*ends) or self.tok.kind == "eof":
                return
            else:
                self.problem(f"expected ',' or the end of the arguments, found {self.tok.text!r}")
                return


def parse_module(text: str, label: str = "module") -> RapidModule:
    """Parse one module; its problems are in ``.problems`` (references not yet resolved:
    see :func:`check_modules`)."""
    return _Parser(text, label).module()


def check_modules(texts: dict[str, str]) -> dict[str, list[str]]:
    """Check modules loaded together into one task: ``{label: text}`` -> ``{label:
    problems}`` (each ``"line N: ..."``; an empty list when a module passes)."""
    mods = {label: parse_module(text, label) for label, text in texts.items()}
    out: dict[str, list[str]] = {}
    for label, mod in mods.items():
        others = [m for m in mods.values() if m is not mod]
        procs = {n for n, (k, _) in mod.routines.items() if k == "PROC"}
        funcs = {n for n, (k, _) in mod.routines.items() if k == "FUNC"}
        data, types = set(mod.data), set(mod.types)
        for m in others:
            procs |= {n for n, (k, local) in m.routines.items() if k == "PROC" and not local}
            funcs |= {n for n, (k, local) in m.routines.items() if k == "FUNC" and not local}
            data |= {n for n, local in m.data.items() if not local}
            types |= m.types
        problems = list(mod.problems)
        for r in mod.refs:
            if r.kind == "instruction" and r.name not in N.INSTRUCTIONS and r.name not in procs:
                why = " (a function: it goes in an expression)" if r.name in N.FUNCTIONS or r.name in funcs else ""
                problems.append(f"line {r.line}: unknown instruction or procedure {r.text}{why}")
            elif r.kind == "function" and r.name not in N.FUNCTIONS and r.name not in funcs:
                why = " (an instruction: it is a statement of its own)" if r.name in N.INSTRUCTIONS or r.name in procs else ""
                problems.append(f"line {r.line}: unknown function {r.text}{why}")
            elif r.kind == "type" and r.name not in N.DATA_TYPES and r.name not in types:
                problems.append(f"line {r.line}: unknown data type {r.text}")
            elif (r.kind == "data" and r.name not in r.scope and r.name not in data
                  and r.name not in N.PREDEFINED_DATA):
                problems.append(f"line {r.line}: unknown data {r.text} (not declared here nor predefined)")
        out[label] = sorted(set(problems), key=lambda p: int(p.split(":")[0].split()[1]))
    return out


def check_module(text: str, label: str = "module") -> list[str]:
    """:func:`check_modules` of one module alone."""
    return check_modules({label: text})[label]


def main(argv: list[str] | None = None) -> int:
    paths = [Path(p) for p in (sys.argv[1:] if argv is None else argv)]
    if not paths:
        print("usage: python -m spherecal.robots.abb_irb2400.rapid_syntax FILE.mod ...", file=sys.stderr)
        return 2
    results = check_modules({str(p): p.read_text(encoding="latin-1") for p in paths})
    bad = False
    for label, problems in results.items():
        for p in problems:
            print(f"{label}: {p}")
        bad |= bool(problems)
    return 1 if bad else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
