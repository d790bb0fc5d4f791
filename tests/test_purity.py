"""The pure core never imports zenoh, time, logging or cv2 (I/O and OpenCV stay at the edges)."""

import ast
import functools
import re
from pathlib import Path

import pytest

FORBIDDEN = {"zenoh", "time", "logging", "socket", "threading", "cv2"}
ROOT = Path(__file__).parent.parent
CORE = sorted((ROOT / "vsfleet").rglob("*.py"))


@functools.lru_cache(maxsize=None)
def absolute_imports(path: Path) -> tuple[str, ...]:
    """The modules ``path`` imports absolutely (``import a.b``, ``from a.b import c``: a.b), in the order they come;
    once per file in a process: the two tests below read the same files (the trees are not kept: held, hundreds of
    them made every garbage collection slower than parsing again)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return tuple(names)


@pytest.mark.parametrize("path", CORE, ids=lambda p: str(p.relative_to(ROOT)))
def test_core_module_imports_no_io(path):
    imported = {name.split(".")[0] for name in absolute_imports(path)}
    assert not imported & FORBIDDEN, f"{path.name} imports {imported & FORBIDDEN}"


PROGRAMS = ("agent", "simfleet", "tracker", "fleetctl", "zglue")  # installed as vsfleet.agent, vsfleet.fleetctl, ...
SOURCES = sorted(p for d in ("vsfleet", *PROGRAMS, "bench", "tests") for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_programs_are_imported_under_the_vsfleet_namespace(path):
    """An import of a top-level agent / fleetctl / ... would work in the repository and fail installed."""
    bad = [n for n in absolute_imports(path) if n.split(".")[0] in PROGRAMS]
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}: use vsfleet.{bad[0]}"


# ---------------------------------------------------------------- the rooms and what each may import
# (docs/architecture.md). Every import counts, also one inside a function.

ROOMS = {  # room -> its folder in the repository, installed as vsfleet.<room> (the core: vsfleet itself)
    "core": "vsfleet", "zglue": "zglue", "agent": "agent", "simfleet": "simfleet", "tracker": "tracker",
    "fleetctl": "fleetctl",
}
MAY_IMPORT = {
    "core": {"core"},                          # the pure core (and its compiled part vsfleet._core)
    "zglue": {"core", "zglue"},                # the Zenoh glue: sessions, lifecycle, peers, scenario files
    "agent": {"core", "zglue", "agent"},       # programs: the core, the glue and their own modules
    "simfleet": {"core", "zglue", "simfleet"},
    "tracker": {"core", "zglue", "tracker"},
    "fleetctl": {"core", "zglue", "fleetctl"},  # tools start programs as processes, never import them
}
EXCEPTIONS = {
    # the one program that composes another: simfleet.offline runs the agents' own code in one process
    # (offline runs, bench and tests), without zenoh
    ("simfleet/offline.py", "agent"),
    # the `vsfleet` command's dispatch table: `vsfleet agent` loads vsfleet.agent.main by name and runs its
    # main as the process the command is (the program's own, started by whoever ran `vsfleet agent`)
    ("fleetctl/cli.py", "agent"), ("fleetctl/cli.py", "simfleet"), ("fleetctl/cli.py", "tracker"),
}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts if parts[0] == "vsfleet" else ["vsfleet", *parts])


def room_of(module: str) -> str | None:
    """The room of an absolute vsfleet.* module name (None: not vsfleet's)."""
    parts = module.split(".")
    if parts[0] != "vsfleet":
        return None
    return parts[1] if len(parts) > 1 and parts[1] in ROOMS and parts[1] != "core" else "core"


DYNAMIC = {"import_module", "__import__", "find_spec", "run_module"}  # importlib's, runpy's: import by a name


def vsfleet_imports(path: Path, text: str | None = None) -> frozenset[str]:
    """_vsfleet_imports of the file's text (or ``text``), memoised by text: rooms' files are read by many tests."""
    return _vsfleet_imports(path, path.read_text() if text is None else text)


@functools.lru_cache(maxsize=None)
def _vsfleet_imports(path: Path, text: str) -> frozenset[str]:
    """Every vsfleet.* module ``path`` (or ``text`` as if it were there) imports, relative imports resolved.

    Also an import by name (importlib.import_module and the like): of a string literal, that module; of
    a computed name (a dispatch table), every vsfleet.* module any string literal in the file names."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    tree = ast.parse(text)
    names = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
             and n.value.split(".")[0] == "vsfleet" and all(part.isidentifier() for part in n.value.split("."))}
    for node in ast.walk(tree):
        called = getattr(node, "func", None)
        called = getattr(called, "attr", getattr(called, "id", None))
        if isinstance(node, ast.Call) and node.args and called in DYNAMIC:
            first = node.args[0]
            if isinstance(first, ast.Constant) and isinstance(first.value, str):
                out.add(first.value)
            else:
                out |= names
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")
            if node.level:
                base = base[:len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            out.add(module)
            out |= {f"{module}.{a.name}" for a in node.names}  # `from . import zconf` imports a module
    return frozenset(m for m in out if m.split(".")[0] == "vsfleet")


ROOM_SOURCES = sorted((room, p) for room, d in ROOMS.items() for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("room,path", ROOM_SOURCES, ids=lambda x: str(x.relative_to(ROOT)) if isinstance(x, Path) else x)
def test_each_room_imports_only_what_it_may(room, path):
    rel = str(path.relative_to(ROOT))
    bad = sorted(m for m in vsfleet_imports(path)
                 if room_of(m) not in MAY_IMPORT[room] and (rel, room_of(m)) not in EXCEPTIONS)
    assert not bad, f"{rel} ({room}) imports {bad}: it may import only {sorted(MAY_IMPORT[room])}"


def import_cycles(room: str, texts: dict[str, str] | None = None) -> list[tuple[str, str]]:
    """The pairs (a, b) of the room's modules where a imports b and b, directly or not, imports a; an
    import inside a function counts. ``texts``: file (relative to the repository) -> text to read instead.
    The room's own package (``vsfleet`` for the core) is left out: ``from . import _core`` imports it."""
    texts = texts or {}
    files = {module_name(p): p for p in (ROOT / ROOMS[room]).rglob("*.py")}
    graph = {m: {i for i in vsfleet_imports(p, texts.get(str(p.relative_to(ROOT)))) if i in files and i != m}
             for m, p in files.items()}

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        return any(n == goal or (n not in seen and not seen.add(n) and reaches(n, goal, seen)) for n in graph[start])

    package = "vsfleet" if room == "core" else f"vsfleet.{room}"
    return sorted((a, b) for a in graph for b in graph[a] if package not in (a, b) and reaches(b, a, set()))


@pytest.mark.parametrize("room", list(ROOMS))
def test_no_two_modules_of_a_room_import_each_other(room):
    """No import cycle inside the core, a program, a tool or the glue (tracker.calibrate and tracker.camera
    did; so did vsfleet.failure and vsfleet.wire, the latter inside functions)."""
    cycles = import_cycles(room)
    assert not cycles, f"import cycles in {room}: {cycles}"


def test_the_cycle_check_sees_an_import_inside_a_function_of_the_core():
    """failure.py importing wire (here inside a function) while wire imports failure is a cycle."""
    failure = (ROOT / "vsfleet" / "failure.py").read_text() + "\n\ndef _probe():\n    from .wire import EVENT_KINDS\n"
    assert import_cycles("core", {"vsfleet/failure.py": failure}) == [("vsfleet.failure", "vsfleet.wire"),
                                                                      ("vsfleet.wire", "vsfleet.failure")]


def test_the_import_rules_catch_a_program_importing_a_tool():
    """The rules above do fail: a program's module that imports a tool (here inside a function) is refused."""
    imported = vsfleet_imports(ROOT / "agent" / "probe.py",
                               "def f():\n    from vsfleet.fleetctl import run\n    from ..fleetctl import plot\n")
    assert {"vsfleet.fleetctl.run", "vsfleet.fleetctl.plot"} <= imported
    assert {room_of(m) for m in imported} - MAY_IMPORT["agent"] == {"fleetctl"}


def test_the_import_rules_catch_a_tool_importing_a_program_by_name():
    """importlib counts: a literal name, and a table of names loaded by a computed one (the only such table,
    the `vsfleet` command's, is an exception above); a child process's command line is no import."""
    probe = ROOT / "fleetctl" / "probe.py"
    assert vsfleet_imports(probe, "import importlib\ndef f():\n    importlib.import_module('vsfleet.agent.main')\n") \
        == {"vsfleet.agent.main"}
    table = "from importlib import import_module\nT = {'a': 'vsfleet.tracker.sim'}\ndef f(k):\n    import_module(T[k])"
    assert vsfleet_imports(probe, table) == {"vsfleet.tracker.sim"}
    assert vsfleet_imports(probe, "import sys\nCMD = [sys.executable, '-m', 'vsfleet.agent.main']\n") == set()
    cli = {m for m in vsfleet_imports(ROOT / "fleetctl" / "cli.py") if room_of(m) not in MAY_IMPORT["fleetctl"]}
    assert {room_of(m) for m in cli} == {"agent", "simfleet", "tracker"}  # seen, and allowed as the table


# ---------------------------------------------------------------- the compiled core's C files (vsfleet/_core)
# No circle among them either: a graph of the files, an edge from a file to every header it includes
# ("...") and from a file to every other file that defines an external function it uses (a call, or
# its address taken) in a function body, an initialiser or a macro.

C_CORE = ROOT / "vsfleet" / "_core"
C_NOT_CALLS = {"if", "for", "while", "switch", "return", "sizeof"}


def c_strip(text: str, strings: bool = True) -> str:
    """C text without its comments and (strings) the contents of its string and char literals;
    newlines are kept."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif strings and c in "\"'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(c + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


@functools.lru_cache(maxsize=None)
def c_parts(text: str) -> tuple[frozenset[str], frozenset[str], frozenset[str]]:
    """(headers included with "...", external functions defined, identifiers used) of one C file.
    Used: in function bodies and initialisers (brace depth >= 1) and in macro bodies; a prototype
    at file scope is no use. Defined: `name(...) {` at file scope, not static."""
    includes = set(re.findall(r'^[ \t]*#[ \t]*include[ \t]*"([^"]+)"', c_strip(text, strings=False), re.M))
    code = c_strip(text)
    directive = r"^[ \t]*#.*(?:\\\n.*)*$"
    macros = " ".join(re.findall(directive, code, re.M))
    macros = " ".join(re.findall(r"#[ \t]*define[ \t]+\w+(?:\([^)]*\))?(.*)", macros, re.S))
    code = re.sub(directive, "", code, flags=re.M)
    defined, used = set(), set(re.findall(r"[A-Za-z_]\w*", macros))
    depth, start = 0, 0
    for m in re.finditer(r"[{};]|[A-Za-z_]\w*", code):
        tok = m.group()
        if tok == "{":
            if depth == 0:
                head = code[start:m.start()]
                f = re.search(r"([A-Za-z_]\w*)\s*\([^;{}=]*\)\s*$", head)
                if f and f.group(1) not in C_NOT_CALLS and not re.search(r"\bstatic\b", head):
                    defined.add(f.group(1))
            depth += 1
        elif tok == "}":
            depth -= 1
            start = m.end() if depth == 0 else start
        elif tok == ";":
            start = m.end() if depth == 0 else start
        elif depth > 0:
            used.add(tok)
    return frozenset(includes), frozenset(defined), frozenset(used)   # memoised (the same files, four graphs)


def c_graph(texts: dict[str, str] | None = None) -> dict[str, set[str]]:
    """File name -> the core's files it depends on (its includes, the files of the functions it uses).
    ``texts``: file name -> text to read instead (or a file that is not there)."""
    files = {p.name: p.read_text() for p in sorted(C_CORE.glob("*.[ch]"))}
    files.update(texts or {})
    parts = {name: c_parts(text) for name, text in files.items()}
    owner: dict[str, set[str]] = {}
    for name, (_, defined, _) in parts.items():
        for fn in defined:
            owner.setdefault(fn, set()).add(name)
    return {name: {h for h in inc if h in files}
            | {o for fn in used - defined for o in owner.get(fn, ()) if o != name}
            for name, (inc, defined, used) in parts.items()}


def c_cycles(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The edges (a, b) of the graph where b reaches a again."""
    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        return any(n == goal or (n not in seen and not seen.add(n) and reaches(n, goal, seen)) for n in graph[start])

    return sorted((a, b) for a in graph for b in graph[a] if reaches(b, a, set()))


def test_no_two_c_files_of_the_compiled_core_depend_on_each_other():
    """vs_fit.c called vs_fit_l1.c and vs_fit_linf.c (the evaluators), which called back into vs_fit.c
    for the helpers they share: those live in vs_fit_common.c now, which depends on neither."""
    graph = c_graph()
    assert not c_cycles(graph), f"circles among the core's C files: {c_cycles(graph)}"
    assert {"vs_fit_l1.c", "vs_fit_linf.c", "vs_fit_common.c"} <= graph["vs_fit.c"]
    assert "vs_fit_common.c" in graph["vs_fit_l1.c"] and "vs_fit_common.c" in graph["vs_fit_linf.c"]


def test_the_c_cycle_check_sees_a_call_back_and_an_include_back():
    """It does fail: the l1 evaluator calling the fit (a circle through vs_fit.c), a header including
    one that includes it; a prototype, a comment or a string naming a function is no call."""
    l1 = (C_CORE / "vs_fit_l1.c").read_text()
    back = l1 + "\nint vs_fit_probe(void)\n{\n    vs_fit_result r;\n    return vs_fit(0, 0, 0, 0, 0, &r);\n}\n"
    assert c_cycles(c_graph({"vs_fit_l1.c": back})) == [("vs_fit.c", "vs_fit_l1.c"), ("vs_fit_l1.c", "vs_fit.c")]
    quiet = l1 + '\nint vs_fit(const double *a, const double *b, const double *w, size_t n, int m, vs_fit_result *o);\n' \
                 '/* vs_fit(...) */\nstatic const char *probe = "vs_fit(";\n'
    assert not c_cycles(c_graph({"vs_fit_l1.c": quiet}))
    math_h = (C_CORE / "vs_math.h").read_text().replace("#define", '#include "vscore.h"\n#define', 1)
    assert ("vs_math.h", "vscore.h") in c_cycles(c_graph({"vs_math.h": math_h}))


def test_no_function_of_the_compiled_core_is_told_apart_by_its_address():
    """vs_fit.c chose linf's flat bound by comparing its evaluator to vs_fit_eval_linf; the metric is
    passed instead."""
    defined = set().union(*(c_parts(p.read_text())[1] for p in C_CORE.glob("*.c")))
    names = "|".join(sorted(defined, key=len, reverse=True))
    bad = [(p.name, m.group()) for p in sorted(C_CORE.glob("*.c"))
           for m in re.finditer(rf"(?:[=!]=\s*(?:{names})\b(?!\s*\())|(?:\b(?:{names})\s*[=!]=)", c_strip(p.read_text()))]
    assert not bad, f"functions compared by address: {bad}"


def _closures(text: str) -> list[str]:
    """Functions defined inside functions, and lambdas, in a module's text: 'name (line)'."""
    found = []

    def visit(node, inside: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Lambda):
                found.append(f"lambda ({child.lineno})")
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if inside:
                    found.append(f"{child.name} ({child.lineno})")
                visit(child, True)
            else:
                visit(child, inside)
    visit(ast.parse(text), False)
    return found


def test_the_agents_wiring_is_named_functions_and_methods_without_closures():
    """Issue 29: agent/main.py wires the agent with module functions and methods (a method's own def is not a
    closure), no function nested in another and no lambda; the check sees both forms."""
    assert _closures("def f():\n    def g():\n        pass\n    return lambda: g\n") == ["g (2)", "lambda (4)"]
    assert _closures("class A:\n    def m(self):\n        return 1\n") == []
    assert _closures((ROOT / "agent" / "main.py").read_text()) == []
