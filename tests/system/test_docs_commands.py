"""Every command README.md and docs/DEPLOY.md tell an operator to type works as written.

The shell blocks of both documents are read the way a shell would (continuation lines
joined, heredoc bodies skipped, `&&`, `|`, `;` and `&` split, `R=...` assignments
remembered), and:

- every `relayd ...` command (also as `/opt/relayd/venv/bin/relayd`, `.venv/bin/relayd`
  or `$R`) is parsed by relayd's real command-line parser, each subcommand with the
  options its module adds: an unknown subcommand, option or choice fails;
- a bare `relayd` is only used after the document has put it on the PATH (the symlink
  to the venv the guide installs);
- every file of this repository a command names (`config/...`, `deploy/...`) exists;
- every HTTP path on a relay's API (`$R/api/mode`, `http://192.168.1.31:8080/status`)
  is one the API serves, and the `curl` commands that command a robot are replayed
  against the real application: same method, headers and body, answered 200.

The `relayd ...` spans in the README's command table are checked the same way for their
subcommands and options.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from aiohttp.test_utils import TestClient, TestServer

from drivers.transport.clock import REAL_CLOCK
from relayd.api.app import make_app
from relayd.cli import build_parser
from relayd.core.vocab import Mode
from relayd.runtime.state import ModeError, RelayState

ROOT = Path(__file__).resolve().parents[2]
DOCS = ("README.md", "docs/DEPLOY.md")
SHELL_LANGS = {"sh", "bash", "shell", "console"}
CONTROL_OPERATORS = {"&&", "||", "|", ";", "&"}
#: What the deployment guide installs, and the link it makes to it on the PATH.
VENV_RELAYD = "/opt/relayd/venv/bin/relayd"
PATH_LINK = "/usr/local/bin/relayd"
REPO_DIRS = ("config/", "systemd/", "deploy/", "docs/", "scripts/", "tests/", "bench/")


@dataclass
class Command:
    doc: str
    line: int
    argv: list[str]
    #: Variables assigned earlier in the document (a reader's shell has them too).
    env: dict[str, str] = field(default_factory=dict)

    def where(self) -> str:
        return f"{self.doc}:{self.line}: {' '.join(self.argv)}"


def shell_blocks(text: str) -> Iterator[tuple[int, list[str]]]:
    """(line number of the first line, lines) of each fenced shell block, indented ones too."""
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^(\s*)```(\w*)\s*$", lines[i])
        if m is None:
            i += 1
            continue
        indent, lang = m.groups()
        end = i + 1
        while end < len(lines) and lines[end].strip() != "```":
            end += 1
        if lang in SHELL_LANGS:
            yield (
                i + 2,
                [
                    line[len(indent) :] if line.startswith(indent) else line
                    for line in lines[i + 1 : end]
                ],
            )
        i = end + 1


def _tokens(line: str) -> list[str]:
    lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    return list(lexer)


def _expand(token: str, env: dict[str, str]) -> str:
    return re.sub(
        r"\$\{?([A-Za-z_][A-Za-z0-9_]*)\}?", lambda m: env.get(m.group(1), m.group(0)), token
    )


def commands(doc: str) -> Iterator[Command]:
    """Every simple command of the document's shell blocks, variables expanded."""
    env: dict[str, str] = {}
    for first, lines in shell_blocks((ROOT / doc).read_text(encoding="utf-8")):
        i = 0
        while i < len(lines):
            lineno, logical = first + i, lines[i]
            while logical.endswith("\\") and i + 1 < len(lines):
                i += 1
                logical = logical[:-1] + " " + lines[i]
            i += 1
            tokens = _tokens(logical)
            if "<<" in tokens:
                delimiter = tokens[tokens.index("<<") + 1]
                while i < len(lines) and lines[i].strip() != delimiter:
                    i += 1
                i += 1
                tokens = tokens[: tokens.index("<<")]
            current: list[str] = []
            for tok in [*tokens, ";"]:
                if tok not in CONTROL_OPERATORS:
                    current.append(tok)
                    continue
                # Redirections take their target with them.
                words = []
                skip = False
                for w in current:
                    if skip:
                        skip = False
                    elif w in (">", ">>", "<", "2>", "&>"):
                        skip = True
                    else:
                        words.append(w)
                assignments = []
                while words and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", words[0]):
                    assignments.append(words.pop(0))
                if words:
                    yield Command(doc, lineno, [_expand(w, env) for w in words], dict(env))
                else:
                    for a in assignments:
                        name, _, value = a.partition("=")
                        env[name] = _expand(value, env)
                current = []


def relayd_commands(doc: str) -> list[Command]:
    return [c for c in commands(doc) if c.argv[0] == "relayd" or c.argv[0].endswith("/relayd")]


def parse_cli(argv: list[str]) -> argparse.Namespace | None:
    """Parse as `relayd.cli.main` does (each subcommand's parser adds its module's options).

    None for `--help`/`--version`, which exit 0. An error raises AssertionError with
    argparse's message.
    """
    parser = build_parser()
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            return parser.parse_args(argv)
    except SystemExit as exc:
        if exc.code == 0:
            return None
        raise AssertionError(err.getvalue().strip()) from None


def test_the_reader_sees_the_commands_a_shell_would() -> None:
    block = [
        "R=/opt/relayd/venv/bin/relayd",
        "$R probe pantilt --port /dev/x \\",
        "    --channel 0 --angle 45   # to the LEFT",
        "cat > f <<'EOF'",
        "relayd nonsense",
        "EOF",
        "TOKEN=t; R2=http://h:8080",
        'A=1 $R status $R2 && echo "$TOKEN" | jq .',
    ]
    doc = ROOT / "README.md"
    text = "```sh\n" + "\n".join(block) + "\n```\n"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Path, "read_text", lambda self, encoding=None: text if self == doc else "")
        found = [c.argv for c in commands("README.md")]
    assert found == [
        [
            "/opt/relayd/venv/bin/relayd",
            "probe",
            "pantilt",
            "--port",
            "/dev/x",
            "--channel",
            "0",
            "--angle",
            "45",
        ],
        ["cat"],
        ["/opt/relayd/venv/bin/relayd", "status", "http://h:8080"],
        ["echo", "t"],
        ["jq", "."],
    ]
    with pytest.raises(AssertionError, match="invalid choice"):
        parse_cli(["probe", "robbot"])
    with pytest.raises(AssertionError, match="unrecognized arguments: --colour"):
        parse_cli(["status", "--colour"])


@pytest.mark.parametrize("doc", DOCS)
def test_every_relayd_command_parses(doc: str) -> None:
    cmds = relayd_commands(doc)
    assert len(cmds) >= 5, f"{doc}: expected relayd commands in its shell blocks"
    for cmd in cmds:
        try:
            parse_cli(cmd.argv[1:])
        except AssertionError as exc:
            raise AssertionError(f"{cmd.where()}\n{exc}") from None


@pytest.mark.parametrize("doc", DOCS)
def test_relayd_is_run_from_where_the_document_installed_it(doc: str) -> None:
    linked = False
    for cmd in commands(doc):
        if cmd.argv[:2] == ["ln", "-sf"] and cmd.argv[2:] == [VENV_RELAYD, PATH_LINK]:
            linked = True
        program = cmd.argv[0]
        if program == "relayd":
            assert linked, f"{cmd.where()}: bare `relayd` before the guide links {PATH_LINK}"
        elif program.endswith("/relayd"):
            assert program in (VENV_RELAYD, PATH_LINK, ".venv/bin/relayd"), cmd.where()
    # The guide's venv is the one the systemd unit runs.
    unit = (ROOT / "systemd" / "relayd.service").read_text(encoding="utf-8")
    assert f"ExecStart={VENV_RELAYD} " in unit


@pytest.mark.parametrize("doc", DOCS)
def test_repository_files_named_by_commands_exist(doc: str) -> None:
    named = 0
    for cmd in commands(doc):
        for word in cmd.argv[1:]:
            word = word.removeprefix("./")
            if word.startswith(REPO_DIRS) and "<" not in word:
                named += 1
                assert (ROOT / word).exists(), f"{cmd.where()}: {word} is not in the repository"
    assert named >= 3


def _api_routes() -> set[tuple[str, str]]:
    app = make_app(RelayState(), _Controls(), clock=REAL_CLOCK, token=None)
    return {(r.method, r.resource.canonical) for r in app.router.routes() if r.resource is not None}


def _api_path(word: str) -> str | None:
    m = re.match(r"^https?://[^/\s]+:8080(/[^\s?#]*)?", word)
    if m is None:
        return None
    return m.group(1) or "/"


@pytest.mark.parametrize("doc", DOCS)
def test_api_paths_in_commands_exist(doc: str) -> None:
    routes = _api_routes()
    for cmd in commands(doc):
        posting = "-d" in cmd.argv or "--data" in cmd.argv
        for word in cmd.argv[1:]:
            path = _api_path(word)
            if path is None:
                continue
            method = "POST" if cmd.argv[0] == "curl" and posting else "GET"
            assert (method, path) in routes, f"{cmd.where()}: the API has no {method} {path}"


class _Controls:
    def __init__(self) -> None:
        self.mode = Mode.HOLD
        self.drives: list[tuple[float, float]] = []

    def set_mode(self, mode: Mode) -> None:
        self.mode = mode

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        if self.mode is not Mode.MANUAL:
            raise ModeError("not in manual mode")
        self.drives.append((left_mm_s, right_mm_s))


def _curl_request(argv: list[str]) -> tuple[str, str, dict[str, str], str | None]:
    """(method, url, headers, body) of a curl command line (the options the guide uses)."""
    headers: dict[str, str] = {}
    body = None
    url = None
    it = iter(argv[1:])
    for word in it:
        if word in ("-H", "--header"):
            name, _, value = next(it).partition(":")
            headers[name.strip()] = value.strip()
        elif word in ("-d", "--data"):
            body = next(it)
        elif word in ("-s", "--silent", "-S", "-f"):
            continue
        elif word.startswith("-"):
            raise AssertionError(f"curl option {word} not understood by this test")
        else:
            url = word
    assert url is not None
    return ("POST" if body is not None else "GET"), url, headers, body


async def test_the_control_curl_commands_work_against_the_api() -> None:
    token = "documented-token-0123456789"
    controls = _Controls()
    state = RelayState()
    app = make_app(state, controls, clock=REAL_CLOCK, token=token)
    posts = [
        c
        for doc in DOCS
        for c in commands(doc)
        if c.argv[0] == "curl" and ("-d" in c.argv or "--data" in c.argv)
    ]
    assert len(posts) >= 3
    async with TestClient(TestServer(app)) as client:
        for cmd in posts:
            argv = [_expand(w.replace("$TOKEN", token).replace("...", token), {}) for w in cmd.argv]
            method, url, headers, body = _curl_request(argv)
            path = _api_path(url)
            assert path is not None, cmd.where()
            resp = await client.request(method, path, headers=headers, data=body)
            assert resp.status == 200, f"{cmd.where()}: {resp.status} {await resp.text()}"
    # The guide's sequences (hold, manual, a drive; the stand test's forward, left only,
    # right only) really reached the robot's controls.
    assert controls.drives == [(100, 100), (100, 100), (100, 0), (0, 100)]


_INLINE = re.compile(r"`(relayd [^`]+)`")


def test_readme_command_table_names_real_subcommands_and_options() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    checked = 0
    for span in _INLINE.findall(text):
        words = span.replace("\\|", "|").split()[1:]
        if not words or words[0] not in _choices():
            raise AssertionError(f"README: `{span}`: no subcommand {words[:1]}")
        path = [words[0]]
        if (
            words[0] in ("probe", "fake", "calibrate")
            and len(words) > 1
            and not words[1].startswith(("-", "[", "."))
        ):
            path.append(words[1])
        for alternative in path[1].split("|") if len(path) > 1 else [None]:
            argv = [path[0]] + ([alternative] if alternative else [])
            parser = _subparser(argv)
            options = set(parser._option_string_actions)
            for opt in re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", " ".join(words)):
                assert opt in options, (
                    f"README: `{span}`: relayd {' '.join(argv)} has no option {opt}"
                )
            checked += 1
    assert checked >= 10


def _choices() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _subparser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser of `relayd <argv>`, with the options its module adds."""
    parser = _choices()[argv[0]]
    if len(argv) > 1:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[argv[1]]
    module = parser.get_default("_module")
    if module is not None:
        importlib.import_module(module).configure(parser)
    return parser
