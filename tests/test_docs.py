"""Docs that cannot drift: what README.md, CONTRIBUTING.md and docs/*.md name exists.

The documents are read as Markdown: inline code spans (whitespace folded, so a span
broken over two lines counts), fenced code blocks, tables, headings and links.  What
they name is found by these patterns, and nothing else is checked, so prose never trips
a test:

* Python names — a dotted name starting ``forest.`` or ``service.`` (the service
  installs as ``forest.service``) inside a code span or a fenced block, and Sphinx roles
  such as ``:func:`forest.x.y```; a name ending in a file suffix (``forest.usdc``) is a
  file.  In a section whose heading names ``forest.<package>``, the modules a sentence
  lists after "Inside…:" (code spans outside parentheses) are ``forest.<package>.<name>``.
  The longest importable module prefix is imported and the rest looked up attribute by
  attribute (a pydantic or dataclass field counts).
* CLI commands — a code span starting ``forest `` and every line of a shell block that
  runs ``forest …``: its command and sub-command words must be commands of the typer app
  in ``forest.cli``, each ``-x``/``--flag`` an option of that command, and
  ``forest <command> --help`` must succeed.  A code span that starts with a flag
  (``--map-prior``) must be an option of some forest command.
* Config settings — code spans ``[section]``, ``[section] key`` (``[[section]]``,
  ``[a.b] key = value``, ``key = { a, b }`` too) and ``section.key`` /
  ``section[i].key`` whose first word is a top-level section; the keys of every ``toml``
  block (commented-out keys included); the cells of a table column headed
  ``[section]``.  All are looked up in the JSON Schema ``forest schema`` prints.
  ``settings.<field>`` is a service job setting, ``GET /route`` a service operation.
* Files — code spans and command arguments that are paths in the checkout
  (``forest/…``, ``configs/…``, ``tests/…``, ``bench/…``, ``scripts/…`` …; a glob must
  match something) and relative Markdown links, with their ``#anchor``.

And the committed OpenAPI document, docs/openapi.json, must equal what the service's
app produces now (``make openapi`` regenerates it).
"""

from __future__ import annotations

import dataclasses
import functools
import glob
import importlib
import importlib.util
import json
import re
import shlex
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC_PATHS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]

# ---------------------------------------------------------------------------
# Markdown: code spans, fenced blocks, tables, links
# ---------------------------------------------------------------------------

FENCE = re.compile(r"^\s*(`{3,}|~{3,})\s*([\w+-]*)")
SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.S)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


@dataclass(frozen=True)
class Span:
    """An inline code span's text (whitespace folded) and where it starts."""

    doc: str
    line: int
    text: str


@dataclass(frozen=True)
class Block:
    """A fenced code block: its language ('' when none), first content line and lines."""

    doc: str
    line: int
    lang: str
    lines: tuple[str, ...]


@dataclass
class Doc:
    name: str
    spans: list[Span] = field(default_factory=list)
    blocks: list[Block] = field(default_factory=list)
    prose: list[tuple[int, str, str]] = field(default_factory=list)  # (first line, paragraph, its heading)
    tables: list[tuple[int, list[list[str]]]] = field(default_factory=list)  # (first line, rows of cells)
    headings: set[str] = field(default_factory=set)  # GitHub anchors


def anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces → '-'."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def parse(name: str, text: str) -> Doc:
    """Split a Markdown text into code spans, fenced blocks, prose paragraphs and tables."""
    doc = Doc(name)
    lines = text.splitlines()
    para: list[str] = []
    para_start, heading = 0, ""

    def flush() -> None:
        if not para:
            return
        chunk = "\n".join(para)
        doc.prose.append((para_start, chunk, heading))
        for m in SPAN.finditer(chunk):
            line = para_start + chunk.count("\n", 0, m.start())
            doc.spans.append(Span(name, line, " ".join(m.group(2).split())))
        if all(p.lstrip().startswith("|") for p in para):
            rows = [[c.strip() for c in re.split(r"(?<!\\)\|", p.strip().strip("|"))] for p in para]
            doc.tables.append((para_start, rows))
        para.clear()

    i = 0
    while i < len(lines):
        line = lines[i]
        fence = FENCE.match(line)
        if fence:
            flush()
            marker, start, body = fence.group(1), i + 2, []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith(marker):
                body.append(lines[i])
                i += 1
            doc.blocks.append(Block(name, start, fence.group(2).lower(), tuple(body)))
        elif not line.strip():
            flush()
        else:
            if line.startswith("#"):
                flush()
                heading = line.lstrip("#").strip()
                doc.headings.add(anchor(heading))
            if not para:
                para_start = i + 1
            para.append(line)
            if line.startswith("#"):
                flush()
        i += 1
    flush()
    return doc


@functools.cache
def docs() -> tuple[Doc, ...]:
    return tuple(parse(p.relative_to(ROOT).as_posix(), p.read_text(encoding="utf-8")) for p in DOC_PATHS)


def where(doc: str, line: int) -> str:
    return f"{doc}:{line}"


# ---------------------------------------------------------------------------
# Python names
# ---------------------------------------------------------------------------

PY_NAME = re.compile(r"(?<![\w./-])((?:forest|service)(?:\.[A-Za-z_]\w*)+)")
ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|const|obj|exc):`~?\.?([\w.]+)`")
# ``forest.usdc`` in "loads `forest.usdc`" is a file of that name, not a module
FILE_SUFFIXES = {
    "usd", "usda", "usdc", "blend", "exr", "png", "jpg", "tif", "tiff", "tex", "hdr", "toml", "json",
    "rib", "ply", "csv", "npz", "obj", "whl", "py", "md", "sl", "sh", "ocio", "txt", "zip",
}  # fmt: skip


def python_names(doc: Doc) -> Iterator[tuple[str, str]]:
    """(where, dotted name) for every forest./service. name in code spans, fenced blocks and roles."""
    texts = [(s.line, s.text) for s in doc.spans]
    texts += [(b.line + k, line) for b in doc.blocks for k, line in enumerate(b.lines)]
    for line, text in texts:
        for m in PY_NAME.finditer(text):
            if m.group(1).rsplit(".", 1)[1] not in FILE_SUFFIXES:
                yield where(doc.name, line), m.group(1)
    for start, text, _ in doc.prose:
        for m in ROLE.finditer(text):
            if m.group(1).startswith(("forest.", "service.")):
                yield where(doc.name, start + text.count("\n", 0, m.start())), m.group(1)
    yield from inside_modules(doc)


INSIDE = re.compile(r"\bInside\b[^:.]*:")
HEADING_PACKAGE = re.compile(r"`(forest\.[\w.]+)`")


def inside_modules(doc: Doc) -> Iterator[tuple[str, str]]:
    """Modules listed in a section on `forest.<package>` after "Inside…:" — the code spans outside
    parentheses up to the sentence's end, as in "Inside: `variant` (…), `jit_frame` (…), …" — as
    `forest.<package>.<module>`."""
    for start, text, heading in doc.prose:
        package = HEADING_PACKAGE.search(heading)
        if not package:
            continue
        for m in INSIDE.finditer(text):
            depth, i = 0, m.end()
            while i < len(text):
                c = text[i]
                if c == "`":
                    end = text.find("`", i + 1)
                    if end < 0:
                        break
                    if depth == 0 and re.fullmatch(r"[a-z_]\w*", text[i + 1 : end]):
                        line = start + text.count("\n", 0, i)
                        yield where(doc.name, line), f"{package.group(1)}.{text[i + 1 : end]}"
                    i = end + 1
                    continue
                depth += {"(": 1, ")": -1}.get(c, 0)
                if c == "." and depth == 0 and (i + 1 == len(text) or text[i + 1].isspace()):
                    break  # the sentence ends
                i += 1


def _has_field(obj: Any, name: str) -> bool:
    fields = getattr(obj, "model_fields", None)  # a pydantic model's fields are not class attributes
    if isinstance(fields, dict) and name in fields:
        return True
    if dataclasses.is_dataclass(obj) and name in {f.name for f in dataclasses.fields(obj)}:
        return True
    return name in getattr(obj, "__annotations__", {})


def missing_python_name(name: str) -> str | None:
    """None when ``name`` resolves; else why not."""
    dotted = "forest." + name if name.startswith("service.") else name  # installed as forest.service
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        module_name = ".".join(parts[:i])
        try:
            found = importlib.util.find_spec(module_name) is not None
        except ImportError:  # a parent is a module, not a package
            found = False
        if found:
            break
    else:
        return f"no module {parts[0]!r}"
    obj: Any = importlib.import_module(module_name)
    owner = module_name
    for part in parts[i:]:
        if hasattr(obj, part):
            obj = getattr(obj, part)
        elif _has_field(obj, part):
            return None  # a field: nothing further to look up on the class
        else:
            return f"{owner} has no {part!r}"
        owner = f"{owner}.{part}"
    return None


def python_problems(documents: tuple[Doc, ...]) -> list[str]:
    out = []
    for doc in documents:
        for at, name in dict.fromkeys(python_names(doc)):
            reason = missing_python_name(name)
            if reason:
                out.append(f"{at}: `{name}`: {reason}")
    return out


# ---------------------------------------------------------------------------
# CLI commands
# ---------------------------------------------------------------------------

SHELL_LANGS = {"", "sh", "bash", "shell", "console", "zsh"}
FLAG = re.compile(r"-{1,2}[A-Za-z][\w-]*")


def command_lines(doc: Doc) -> Iterator[tuple[str, str]]:
    """(where, 'forest …') for code spans and shell-block lines that run forest."""
    for s in doc.spans:
        if s.text.startswith("forest "):
            yield where(doc.name, s.line), s.text
    for b in doc.blocks:
        if b.lang not in SHELL_LANGS:
            continue
        joined: list[tuple[int, str]] = []
        for k, line in enumerate(b.lines):
            if joined and joined[-1][1].endswith("\\"):
                joined[-1] = (joined[-1][0], joined[-1][1][:-1] + " " + line.strip())
            else:
                joined.append((b.line + k, line.strip()))
        for line_no, line in joined:
            line = re.sub(r"(^|\s)#.*$", "", line.removeprefix("$ "))
            for part in re.split(r"\s*(?:&&|\|\||;|\s\|\s)\s*", line):
                if part.startswith("forest "):
                    yield where(doc.name, line_no), part.strip()


@functools.cache
def cli_root() -> Any:
    import typer.main

    from forest.cli import app

    return typer.main.get_command(app)


def resolve_command(text: str) -> tuple[list[str] | None, str | None]:
    """(the command's words, None) or (None, why it is not a command of the CLI)."""
    try:
        tokens = shlex.split(text)
    except ValueError:
        tokens = text.split()
    tokens = [t.strip("[]") for t in tokens[1:]]  # "[--render x.png]" marks an optional part
    cmd, words = cli_root(), []
    while hasattr(cmd, "commands") and tokens and not tokens[0].startswith("-"):
        word = tokens.pop(0)
        if word.startswith("<") or "…" in word:  # a placeholder: `forest <command> --help`
            return None, None
        sub = cmd.commands.get(word)
        if sub is None:
            known = ", ".join(sorted(cmd.commands))
            return None, f"`{' '.join(['forest', *words])}` has no command {word!r} (it has {known})"
        cmd = sub
        words.append(word)
    options = {"-h", "--help"} | {o for p in cmd.params for o in (*p.opts, *getattr(p, "secondary_opts", ()))}
    for token in tokens:
        flag = token.split("=", 1)[0]
        if FLAG.fullmatch(flag) and flag not in options:
            return None, f"`{' '.join(['forest', *words])}` has no option {flag}"
    return words, None


# Flags of other programs that the docs show in a code span of their own: `ray start`'s and
# the benchmark scripts'.  A span that is just a flag is otherwise one of forest's.
OTHER_PROGRAMS_FLAGS = {"--num-cpus", "--num-gpus", "--object-store-memory", "--case", "--only"}


@functools.cache
def all_options() -> frozenset[str]:
    """Every option of every forest command."""
    out, todo = {"-h", "--help"}, [cli_root()]
    while todo:
        cmd = todo.pop()
        out |= {o for p in cmd.params for o in (*p.opts, *getattr(p, "secondary_opts", ()))}
        todo += list(getattr(cmd, "commands", {}).values())
    return frozenset(out)


def cli_problems(documents: tuple[Doc, ...]) -> tuple[list[str], set[tuple[str, ...]]]:
    """What is wrong with the commands the docs show, and the command paths they show."""
    out, seen = [], set()
    for doc in documents:
        for at, text in command_lines(doc):
            words, reason = resolve_command(text)
            if reason:
                out.append(f"{at}: `{text}`: {reason}")
            elif words is not None:
                seen.add(tuple(words))
        for s in doc.spans:  # `--map-prior`, `--mode statistics`: a flag on its own
            flag = s.text.split()[0].split("=", 1)[0]
            if FLAG.fullmatch(flag) and flag not in all_options() | OTHER_PROGRAMS_FLAGS:
                out.append(
                    f"{where(doc.name, s.line)}: `{s.text}`: no forest command has the option {flag}"
                    " (another program's flag? add it to OTHER_PROGRAMS_FLAGS)"
                )
    return out, seen


# ---------------------------------------------------------------------------
# Config settings
# ---------------------------------------------------------------------------

BRACKETED = re.compile(r"\[\[?([a-z_]\w*(?:\.[a-z_]\w*)*)\]\]?(?:\s+([a-z_]\w*)(?:\s*=\s*(.+))?)?")
SEGMENT = r"[a-z_]\w*(?:\[\w*\])?"
DOTTED = re.compile(rf"({SEGMENT}(?:\.{SEGMENT})+)(?:\s*=.*)?")
QUOTED = re.compile(r"\"([a-z_][\w.\[\]]*)\"")
HEADER_CELL = re.compile(r"`\[([a-z_]\w*(?:\.[a-z_]\w*)*)\]`")


@functools.cache
def config_schema() -> dict[str, Any]:
    """The JSON Schema `forest schema` prints."""
    from forest.config.schema import SceneConfig

    return SceneConfig.model_json_schema()


def _concrete(node: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """A schema node with its $refs followed and its unions opened."""
    if "$ref" in node:
        yield from _concrete(config_schema()["$defs"][node["$ref"].rsplit("/", 1)[1]])
        return
    unions = [b for key in ("anyOf", "oneOf", "allOf") for b in node.get(key, ())]
    if unions:
        for branch in unions:
            yield from _concrete(branch)
    else:
        yield node


def _children(nodes: list[dict[str, Any]], key: str) -> list[dict[str, Any]]:
    out = []
    for node in (c for n in [*nodes, *_items(nodes)] for c in _concrete(n)):  # `[[species]] model` is in the items
        if key in node.get("properties", {}):
            out.append(node["properties"][key])
            continue
        out += [sub for pattern, sub in node.get("patternProperties", {}).items() if re.search(pattern, key)]
        extra = node.get("additionalProperties")
        if isinstance(extra, dict):
            out.append(extra)
        elif extra is True or (node.get("type") == "object" and "properties" not in node and extra is None):
            out.append({})
    return out


def _items(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [c["items"] for n in nodes for c in _concrete(n) if isinstance(c.get("items"), dict)]


def missing_setting(path: list[str]) -> str | None:
    """None when the dotted path (segments may carry [i]) is in the schema; else the first unknown part."""
    nodes = [config_schema()]
    done: list[str] = []
    for segment in path:
        key, indexed = segment.split("[", 1)[0], "[" in segment
        nodes = _children(nodes, key)
        if not nodes:
            return f"no setting {'.'.join([*done, key])!r}" if done else f"no section [{key}]"
        if indexed:
            nodes = _items(nodes)
            if not nodes:
                return f"{'.'.join([*done, key])} is not a list"
        done.append(segment)
    return None


def table_problems(data: dict[str, Any], prefix: list[str]) -> Iterator[str]:
    """The keys of a parsed TOML table that the schema does not have."""
    for key, value in data.items():
        path = [*prefix, key]
        reason = missing_setting(path)
        if reason:
            yield reason
            continue
        if isinstance(value, dict):
            yield from table_problems(value, path)
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for v in value:
                yield from table_problems(v, [*prefix, key + "[]"])


def inline_keys(value: str) -> list[dict[str, Any]]:
    """`{ a = 1, b = 2 }` or `{ a, b, c }` (keys listed without values) as tables of keys."""
    try:
        parsed = tomllib.loads(f"x = {value}")["x"]
    except tomllib.TOMLDecodeError:
        if not value.startswith("{"):
            return []
        names = [m.group(1) for item in value.strip("{} ").split(",") if (m := re.match(r"\s*([a-z_]\w*)\s*$", item))]
        return [dict.fromkeys(names)]
    return [parsed] if isinstance(parsed, dict) else []


def settings_named(doc: Doc) -> Iterator[tuple[str, list[str], str]]:
    """(where, dotted path, as written) for every config setting a code span names."""
    sections = set(config_schema()["properties"])
    for s in doc.spans:
        at = where(doc.name, s.line)
        m = BRACKETED.fullmatch(s.text)
        if m:
            section, key, value = m.group(1).split("."), m.group(2), m.group(3)
            if key is None:
                yield at, section, s.text
                continue
            path = [*section, key]
            yield at, path, s.text
            for table in inline_keys(value) if value else ():
                for sub in table:
                    yield at, [*path, sub], s.text
            continue
        parts = s.text.split("/") if all(DOTTED.fullmatch(p) for p in s.text.split("/")) else [s.text]
        parts += QUOTED.findall(s.text)
        for part in parts:
            d = DOTTED.fullmatch(part)
            if (
                d
                and d.group(1).split(".")[0].split("[")[0] in sections
                and d.group(1).rsplit(".", 1)[1] not in FILE_SUFFIXES
            ):
                yield at, d.group(1).split("."), s.text
    for line, rows in doc.tables:
        header = rows[0]
        for col, cell in enumerate(header):
            h = HEADER_CELL.fullmatch(cell)
            if not h:
                continue
            for k, row in enumerate(rows[2:], start=2):
                if col < len(row):
                    for key in re.findall(r"`([a-z_]\w*)`", row[col]):
                        yield where(doc.name, line + k), [*h.group(1).split("."), key], f"{cell} {key}"


def toml_blocks(doc: Doc) -> Iterator[tuple[str, str]]:
    """(where, text) of each toml block, with commented-out `# key = value` lines switched on."""
    for b in doc.blocks:
        if b.lang != "toml":
            continue
        lines = []
        for line in b.lines:
            if re.match(r"\s*#\s*[a-z_]\w*\s*=", line):
                line = re.sub(r"^\s*#\s*", "", line)
                line = line.replace("[...]", "[]").replace(", ...", "").replace("...", "")
            lines.append(line)
        yield where(doc.name, b.line), "\n".join(lines)


def config_problems(documents: tuple[Doc, ...]) -> list[str]:
    out = []
    for doc in documents:
        for at, path, written in settings_named(doc):
            reason = missing_setting(path)
            if reason:
                out.append(f"{at}: `{written}`: {reason}")
        for at, text in toml_blocks(doc):
            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as e:
                out.append(f"{at}: the toml block does not parse (commented keys switched on): {e}")
                continue
            out += [f"{at}: toml block: {reason}" for reason in table_problems(data, [])]
    return out


# ---------------------------------------------------------------------------
# Files in the checkout
# ---------------------------------------------------------------------------

REPO_PATH = re.compile(r"(?:forest|service|plugins|library|configs|scripts|tests|bench|docs|\.ci)/[\w.*/-]*")


def paths_named(doc: Doc) -> Iterator[tuple[str, str, Path]]:
    """(where, as written, the folder it is relative to) for repo paths in spans, commands and links."""
    for s in doc.spans:
        if REPO_PATH.fullmatch(s.text):
            yield where(doc.name, s.line), s.text, ROOT
    for at, text in command_lines(doc):
        for token in text.split():
            if REPO_PATH.fullmatch(token):
                yield at, token, ROOT
    base = (ROOT / doc.name).parent
    for start, text, _ in doc.prose:
        for m in LINK.finditer(text):
            target = m.group(1)
            if not re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, mailto: …
                yield where(doc.name, start + text.count("\n", 0, m.start())), target, base


def path_problems(documents: tuple[Doc, ...]) -> list[str]:
    out = []
    for doc in documents:
        for at, written, base in paths_named(doc):
            path, _, fragment = written.partition("#")
            target = (base / path) if path else ROOT / doc.name
            if "*" in path:
                if not glob.glob(str(target)):
                    out.append(f"{at}: `{written}` matches no file")
                continue
            if not target.exists():
                out.append(f"{at}: `{written}` does not exist")
            elif fragment and target.suffix == ".md":
                headings = parse(written, target.read_text(encoding="utf-8")).headings
                if fragment not in headings:
                    out.append(f"{at}: `{written}`: no heading #{fragment} in {path or doc.name}")
    return out


# ---------------------------------------------------------------------------
# The service's API
# ---------------------------------------------------------------------------


@functools.cache
def openapi_generator() -> Any:
    """scripts/make_openapi.py, the one place the committed document is made."""
    spec = importlib.util.spec_from_file_location("make_openapi", ROOT / "scripts" / "make_openapi.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.cache
def openapi_now() -> str:
    return str(openapi_generator().openapi_text())


ROUTE = re.compile(r"(GET|POST|PUT|PATCH|DELETE) (/[^\s?`]*)")


def route_problems(documents: tuple[Doc, ...]) -> list[str]:
    """`GET /jobs/{id}` and the like that the service's OpenAPI document does not have."""
    paths = json.loads(openapi_now())["paths"]
    known = {(m.upper(), re.sub(r"\{[^}]*\}", "{}", route)) for route, ops in paths.items() for m in ops}
    return [
        f"{where(doc.name, s.line)}: `{s.text}`: the service has no such route"
        for doc in documents
        for s in doc.spans
        if (m := ROUTE.fullmatch(s.text)) and (m.group(1), re.sub(r"\{[^}]*\}", "{}", m.group(2))) not in known
    ]


# ---------------------------------------------------------------------------
# The tests
# ---------------------------------------------------------------------------


def stale(kind: str, problems: list[str]) -> str:
    return f"{len(problems)} stale {kind} in the docs (fix the doc text):\n  " + "\n  ".join(problems)


def test_python_names_in_the_docs_exist():
    """Every forest./service. module, class, function and constant the docs name imports or resolves."""
    names = {name for doc in docs() for _, name in python_names(doc)}
    assert {"forest.scene.load_scene", "forest.render.path.from_scene.path_inputs"} <= names
    problems = python_problems(docs())
    assert not problems, stale("Python names", problems)


def test_cli_commands_in_the_docs_exist():
    """Every `forest <command> [<sub-command>] [--flags]` the docs show is a command of the CLI with
    those options, and `--help` on it succeeds."""
    from typer.testing import CliRunner

    from forest.cli import app

    problems, seen = cli_problems(docs())
    assert not problems, stale("CLI commands", problems)
    assert {("render",), ("export", "rib"), ("library", "list"), ("serve",), ("match",)} <= seen
    runner = CliRunner()
    for words in sorted(seen):
        result = runner.invoke(app, [*words, "--help"])
        assert result.exit_code == 0, f"forest {' '.join(words)} --help: exit {result.exit_code}\n{result.output}"


def test_config_settings_in_the_docs_exist():
    """Every `[section] key`, `section.key`, `[section]` table column and toml example key the docs
    give is a setting of the scene-file schema."""
    named = {".".join(p) for doc in docs() for _, p, _ in settings_named(doc)}
    assert {"render.terrain_texture", "lookdev.leaf_tint", "lights.sun.irradiance", "lookdev.map_prior"} <= named
    problems = config_problems(docs())
    assert not problems, stale("config settings", problems)


def test_readme_example_scene_file_is_a_valid_config():
    """The README's scene file, as written, passes the schema (its input files aside)."""
    from forest.config.schema import SceneConfig

    readme = next(d for d in docs() if d.name == "README.md")
    block = next(b for b in readme.blocks if b.lang == "toml")
    SceneConfig.model_validate(tomllib.loads("\n".join(block.lines)), context={"check_files": False})


def test_service_job_settings_in_the_docs_exist():
    """Every `settings.<field>` the docs name is a field of a service job's settings."""
    from forest.service.jobs import JobSettings

    problems = [
        f"{where(doc.name, s.line)}: `{s.text}`: no job setting {m.group(1)!r}"
        for doc in docs()
        for s in doc.spans
        for m in re.finditer(r"(?<![\w.])settings\.(\w+)", s.text)
        if m.group(1) not in JobSettings.model_fields
    ]
    assert not problems, stale("job settings", problems)


def test_service_routes_in_the_docs_exist():
    """Every `METHOD /route` the docs give is an operation of the service's API."""
    named = [s.text for doc in docs() for s in doc.spans if ROUTE.fullmatch(s.text)]
    assert "POST /jobs" in named
    problems = route_problems(docs())
    assert not problems, stale("routes", problems)


def test_files_and_links_in_the_docs_exist():
    """Every path in the checkout the docs name (forest/…, configs/…, tests/…, bench/*.py …) and every
    relative link, with its #anchor, points at something that exists."""
    problems = path_problems(docs())
    assert not problems, stale("paths", problems)


def test_the_checks_catch_renamed_and_removed_names():
    """A renamed or removed module, function, command, option, setting, file or heading in a doc is
    reported, and the real names it was made from are not: the patterns find names and the checks bite."""
    bad = parse(
        "docs/example.md",
        "Call `forest.scene.load_scen` and :func:`forest.scene.no_such_function`; run `forest exprt rib`\n"
        "or `forest render scene.toml --previw`; set `[render] terrain_textur`, `[rendr] view`,\n"
        "`lights.sky.envmapp`, `[lights.sky] sunsky = { turbidity, albedoo }`; see `forest/no_such.py`\n"
        "and [the haze](rendering.md#no-such-heading).\n\n"
        "```sh\nforest library lst\n```\n\n"
        "```toml\n[render]\nwidth = 64\n# spp_count = 4\n```\n\n"
        "| option | `[lookdev]` |\n|---|---|\n| `--mode` | `moode` |\n\n"
        "The `--map-priors` option; `GET /job/{id}`.\n\n"
        "### Render — `forest.render`\nInside: `variant` (the `llvm_ad_rgb` choice), `no_such_module`. Not `this`.\n",
    )
    python = "\n".join(python_problems((bad,)))
    assert "load_scen" in python and "no_such_function" in python and "forest.render.no_such_module" in python, python
    assert "variant" not in python and "llvm_ad_rgb" not in python and "this" not in python, python
    cli = "\n".join(cli_problems((bad,))[0])
    assert "'exprt'" in cli and "--previw" in cli and "'lst'" in cli and "--map-priors" in cli, cli
    config = "\n".join(config_problems((bad,)))
    for name in ("terrain_textur", "[rendr]", "envmapp", "albedoo", "spp_count", "moode"):
        assert name in config, f"{name} not reported:\n{config}"
    paths = "\n".join(path_problems((bad,)))
    assert "forest/no_such.py" in paths and "#no-such-heading" in paths, paths
    assert "GET /job/{id}" in "\n".join(route_problems((bad,)))

    good = parse(
        "docs/example.md",
        "Call `forest.scene.load_scene`; run `forest export rib` or `forest render scene.toml --preview`;\n"
        "set `[render] terrain_texture`, `[render] view`, `lights.sky.envmap`,\n"
        "`[lights.sky] sunsky = { turbidity, albedo }`; see `forest/scene.py` and\n"
        "[the haze](rendering.md#aerial-perspective-haze).\n\n"
        "| option | `[lookdev]` |\n|---|---|\n| `--mode` | `mode` |\n\n"
        "The `--map-prior` option; `GET /jobs/{id}`.\n\n"
        "### Render — `forest.render`\nInside: `variant` (the `llvm_ad_rgb` choice), `jit_frame`. Not `this`.\n",
    )
    checks = (python_problems, config_problems, path_problems, route_problems)
    assert not [p for check in checks for p in check((good,))] + cli_problems((good,))[0]


def test_committed_openapi_document_is_current():
    """docs/openapi.json is byte for byte the OpenAPI document the service's app produces now."""
    committed = openapi_generator().OUTPUT
    assert committed.is_file(), "docs/openapi.json is missing: run `make openapi`"
    now = openapi_now()
    if committed.read_text(encoding="utf-8") != now:
        old, new = json.loads(committed.read_text(encoding="utf-8")), json.loads(now)
        changed = sorted(
            f"{method.upper()} {route}"
            for route in old["paths"].keys() | new["paths"].keys()
            for method in old["paths"].get(route, {}).keys() | new["paths"].get(route, {}).keys()
            if old["paths"].get(route, {}).get(method) != new["paths"].get(route, {}).get(method)
        )
        pytest.fail(
            "docs/openapi.json is stale: the service's API changed; run `make openapi` and commit the result"
            + (f" (operations that differ: {', '.join(changed)})" if changed else " (schemas or metadata differ)")
        )
