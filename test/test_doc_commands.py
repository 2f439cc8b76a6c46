"""Every command the README and doc/ show is checked here, so the documentation cannot drift.

Each fenced ``bash`` block is read command by command (``&&``, ``||``, ``;``, ``|`` and line
continuations split and joined as bash does, comments dropped):

- ``audio2pose ...`` (also ``.venv/bin/audio2pose``, ``.venv-jazzy/bin/audio2pose`` and
  ``ros2 run audio2pose_ros audio2pose``)
  is parsed by the real argument parser: verb, options and their values; nothing heavy runs.
  An ``audio2pose console`` of an ordinary block also has its bind, certificate and token checked
  as the command checks them before it starts anything.
- ``make <target> [NAME=value]`` must name a target of the Makefile;
  ``ros2 launch audio2pose_ros pepper.launch.py name:=value`` must name declared launch
  arguments, with a value among their choices; ``python -m <module>`` must be importable.
- ``openssl`` runs for real, in a temporary directory.

A block whose first line is ``# needs ...`` (a ROS 2 distro, the robot, a clone of another
repository) shows commands that cannot run here: it is checked with ``bash -n`` and the checks
above, and its other commands only for syntax. Any other program in an ordinary block fails the
test: mark the block, or teach this test to check it. Inline code that starts with
``audio2pose `` is checked too, as a reference: its verb and its options must exist (it may be a
synopsis with ``[...]``).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import re
import shlex
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from audio2pose_ros.cli.main import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "doc").glob("*.md"))]
NEEDS = re.compile(r"^# needs \S")
FENCE = re.compile(r"^(`{3,})(.*)$")
SEPARATORS = {"&&", "||", ";", "|", "&"}
REDIRECTIONS = {">", ">>", "<", ">&", "<&", "2>", "&>"}
AUDIO2POSE_PREFIXES = (
    ["audio2pose"],
    [".venv/bin/audio2pose"],
    [".venv-jazzy/bin/audio2pose"],
    ["ros2", "run", "audio2pose_ros", "audio2pose"],
)


@dataclass(frozen=True)
class Block:
    """One fenced code block: where it is, its language, its text."""

    path: Path
    line: int
    language: str
    text: str

    @property
    def needs(self) -> bool:
        """Marked as needing what this machine has not (a distro, the robot, ...)."""
        first = self.text.lstrip("\n").splitlines()[0] if self.text.strip() else ""
        return bool(NEEDS.match(first))

    def __str__(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def fenced_blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a Markdown file (backtick fences, any length)."""
    blocks: list[Block] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    index = 0
    while index < len(lines):
        opening = FENCE.match(lines[index])
        if not opening:
            index += 1
            continue
        fence, language = opening.group(1), opening.group(2).strip()
        body: list[str] = []
        index += 1
        while index < len(lines) and not lines[index].startswith(fence):
            body.append(lines[index])
            index += 1
        blocks.append(Block(path, index - len(body), language, "\n".join(body) + "\n"))
        index += 1
    return blocks


def prose(path: Path) -> str:
    """The Markdown text outside fenced blocks."""
    kept, fence = [], ""
    for line in path.read_text(encoding="utf-8").splitlines():
        opening = FENCE.match(line)
        if opening and not fence:
            fence = opening.group(1)
        elif fence and line.startswith(fence):
            fence = ""
        elif not fence:
            kept.append(line)
    return "\n".join(kept)


def _simple(words: list[str]) -> list[str]:
    """``words`` without redirections (and their targets), leading assignments and sudo."""
    kept: list[str] = []
    skip = False
    for index, word in enumerate(words):
        if skip:
            skip = False
            continue
        if word in REDIRECTIONS:
            skip = True
            continue
        following = words[index + 1] if index + 1 < len(words) else ""
        if word.isdigit() and following in REDIRECTIONS:
            continue  # the descriptor of 2>/dev/null
        kept.append(word)
    while kept and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", kept[0]):
        kept.pop(0)
    if kept[:1] == ["sudo"]:
        kept.pop(0)
    return kept


def script_commands(script: str) -> list[list[str]]:
    """Each line (continuations joined) split into its simple commands."""
    joined = script.replace("\\\n", " ")
    found: list[list[str]] = []
    for line in joined.splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|<>")
        lexer.whitespace_split = True
        lexer.commenters = "#"
        current: list[str] = []
        for token in lexer:
            if token in SEPARATORS:
                if _simple(current):
                    found.append(_simple(current))
                current = []
            else:
                current.append(token)
        if _simple(current):
            found.append(_simple(current))
    return found


# --- what each kind of command is checked against ---------------------------------------------


def audio2pose_arguments(words: list[str]) -> list[str] | None:
    """The arguments of an ``audio2pose`` command, or None when ``words`` is another program."""
    for prefix in AUDIO2POSE_PREFIXES:
        if words[: len(prefix)] == prefix:
            return words[len(prefix) :]
    return None


def parse_audio2pose(arguments: list[str]) -> argparse.Namespace:
    """``arguments`` parsed by the real parser; AssertionError with its message if refused."""
    errors = io.StringIO()
    try:
        with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
            return build_parser().parse_args(arguments)
    except SystemExit as exc:
        if exc.code == 0:  # --help
            return argparse.Namespace(verb=None)
        raise AssertionError(f"audio2pose {shlex.join(arguments)}: {errors.getvalue()}") from None


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The sub-parsers (verbs) of ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def check_reference(arguments: list[str]) -> None:
    """An inline mention: the verb (and sub-verb) exist and every ``--option`` is theirs."""
    parser: argparse.ArgumentParser = build_parser()
    words = [w for w in arguments if w != "--debug"]
    if words and words[0].startswith("<"):  # any verb (``audio2pose <verb> --help``)
        return
    while words and subparsers(parser) and words[0] in subparsers(parser):
        parser = subparsers(parser)[words.pop(0)]
    if subparsers(parser):
        raise AssertionError(f"audio2pose {shlex.join(arguments)}: no such verb")
    for word in words:
        option = re.match(r"^(--[a-z][a-z0-9-]*)", word)
        if option and option.group(1) not in parser._option_string_actions:
            raise AssertionError(f"audio2pose {shlex.join(arguments)}: no option {option.group(1)}")


def make_targets() -> set[str]:
    """The targets of the Makefile."""
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    return set(re.findall(r"^([a-z][a-z-]*):", text, flags=re.MULTILINE))


def launch_arguments() -> dict[str, list[str] | None]:
    """The launch file's declared arguments and their choices (None: any value)."""
    tree = ast.parse((ROOT / "launch" / "pepper.launch.py").read_text(encoding="utf-8"))
    declared: dict[str, list[str] | None] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument":
            name = ast.literal_eval(node.args[0])
            choices = next((k.value for k in node.keywords if k.arg == "choices"), None)
            declared[name] = ast.literal_eval(choices) if choices is not None else None
    return declared


def check_launch(words: list[str]) -> None:
    """``ros2 launch audio2pose_ros pepper.launch.py ...``: declared arguments, allowed values."""
    declared = launch_arguments()
    assert words[3:4] == ["pepper.launch.py"], f"no launch file {words[3:4]}"
    for word in words[4:]:
        if word == "--show-args":
            continue
        name, assigned, value = word.partition(":=")
        assert assigned, f"{shlex.join(words)}: {word!r} is not name:=value"
        assert name in declared, f"{shlex.join(words)}: no launch argument {name}"
        choices = declared[name]
        assert choices is None or value in choices or value.startswith("$"), (
            f"{shlex.join(words)}: {name} takes {choices}, not {value!r}"
        )


def check_console(namespace: argparse.Namespace, cwd: Path) -> None:
    """``audio2pose console``'s own check of bind, certificate and token, before it starts."""
    from audio2pose_ros.errors import ConfigurationError
    from audio2pose_ros.ros.console_runner import check_console_settings

    values: dict[str, object] = {
        name: getattr(namespace, name)
        for name in ("host", "port", "token")
        if getattr(namespace, name) is not None
    }
    for name in ("certfile", "keyfile"):
        if getattr(namespace, name):
            values[name] = str(cwd / getattr(namespace, name))
    try:
        check_console_settings(None, values)
    except ConfigurationError as exc:
        raise AssertionError(f"audio2pose console refuses: {exc}") from None


def check_block(block: Block, tmp: Path) -> list[str]:
    """What is wrong with the commands of ``block`` (empty when nothing is)."""
    problems: list[str] = []
    syntax = subprocess.run(["bash", "-n"], input=block.text, capture_output=True, text=True)
    if syntax.returncode:
        problems.append(f"{block}: bash -n: {syntax.stderr.strip()}")
    try:
        split = script_commands(block.text)
    except ValueError as exc:  # an unterminated quote
        return [*problems, f"{block}: cannot split into commands: {exc}"]
    for words in split:
        try:
            check_command(words, block, tmp)
        except AssertionError as exc:
            problems.append(f"{block}: {exc}")
    return problems


def check_command(words: list[str], block: Block, tmp: Path) -> None:
    """Check one command of ``block`` (see the module text)."""
    arguments = audio2pose_arguments(words)
    if arguments is not None:
        namespace = parse_audio2pose(arguments)
        if namespace.verb == "console" and not block.needs:
            check_console(namespace, tmp)
    elif words[0] == "make":
        unknown = {word for word in words[1:] if "=" not in word} - make_targets()
        assert not unknown, f"make: no target {sorted(unknown)}"
    elif words[:3] == ["ros2", "launch", "audio2pose_ros"]:
        check_launch(words)
    elif words[:2] == ["python", "-m"] and words[2].startswith("audio2pose_ros"):
        import importlib.util

        assert importlib.util.find_spec(words[2]), f"no module {words[2]}"
    elif words[0] == "openssl" and not block.needs:
        assert shutil.which("openssl"), "openssl is not installed"
        result = subprocess.run(words, cwd=tmp, capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, f"{shlex.join(words)}: {result.stderr[-500:]}"
    elif not block.needs:
        raise AssertionError(
            f"{words[0]}: not checked here; start the block with '# needs ...' if it cannot run"
        )


def shell_blocks() -> list[Block]:
    """Every shell block of the README and doc/."""
    return [
        block
        for path in DOCS
        for block in fenced_blocks(path)
        if block.language in {"bash", "sh", "shell", "console"}
    ]


@pytest.mark.parametrize("block", shell_blocks(), ids=str)
def test_every_shell_block_is_checked(block: Block, tmp_path: Path):
    assert block.language == "bash", "shell blocks are ```bash, one kind for the test to read"
    assert check_block(block, tmp_path) == []


def inline_references() -> list[tuple[Path, str]]:
    """Inline code spans of the prose that start with ``audio2pose ``."""
    found = []
    for path in DOCS:
        for span in re.findall(r"(?<!`)`([^`\n]+)`(?!`)", prose(path)):
            if span.startswith("audio2pose "):
                found.append((path, span))
    return found


@pytest.mark.parametrize(
    ("path", "span"), inline_references(), ids=lambda v: v if isinstance(v, str) else v.name
)
def test_every_inline_audio2pose_reference_names_a_verb_and_its_options(path: Path, span: str):
    words = span.replace("\\|", "|").split()
    check_reference(words[1:])


def test_the_readme_names_the_two_commands_and_ci_runs_its_test_command():
    """.ci/run must run what the README tells users to run."""
    first = next(b for b in fenced_blocks(ROOT / "README.md") if b.language == "bash")
    assert script_commands(first.text) == [["make", "demo"], ["make", "test"]]
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert "make test" in ci


def test_the_readme_fits_two_screens_and_links_every_page():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    for page in sorted((ROOT / "doc").glob("*.md")):
        if page.name != "index.md":
            assert f"(doc/{page.name}" in readme, f"README links no doc/{page.name}"
    for target in re.findall(r"\]\(([^)#]+)", readme):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links {target}, which does not exist"


# --- the checker itself -----------------------------------------------------------------------


def test_checker_splits_commands_as_bash_does():
    script = (
        "# a comment\nS1=/tmp/x rm $S1/a.mpg   # why\nsudo rosdep init 2>/dev/null; rosdep update\n"
        "cd ws && audio2pose train \\\n  --model live --data d -o m.safetensors | tee log\n"
    )
    assert script_commands(script) == [
        ["rm", "$S1/a.mpg"],
        ["rosdep", "init"],
        ["rosdep", "update"],
        ["cd", "ws"],
        ["audio2pose", "train", "--model", "live", "--data", "d", "-o", "m.safetensors"],
        ["tee", "log"],
    ]


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("audio2pose run --no-such-option\n", "unrecognized arguments"),
        ("audio2pose nosuchverb\n", "invalid choice"),
        ("make nosuchtarget\n", "no target"),
        ("ros2 launch audio2pose_ros pepper.launch.py sim:=mujoco\n", "sim takes"),
        ("ros2 launch audio2pose_ros pepper.launch.py nosuch:=1\n", "no launch argument"),
        ("rm -rf build\n", "not checked here"),
        ("audio2pose run --play 'unterminated\n", "bash -n"),
        ("audio2pose console --host 0.0.0.0\n", "audio2pose console refuses"),  # no certificate
    ],
)
def test_checker_reports_a_command_the_code_does_not_accept(tmp_path, text, problem):
    block = Block(ROOT / "README.md", 1, "bash", text)
    problems = check_block(block, tmp_path)
    assert problems, text
    assert problem in " ".join(problems)


def test_checker_lets_a_marked_block_name_programs_it_cannot_run(tmp_path):
    marked = Block(ROOT / "README.md", 1, "bash", "# needs the robot\nros2 topic pub /x y z\n")
    assert check_block(marked, tmp_path) == []
    wrong = Block(ROOT / "README.md", 1, "bash", "# needs the robot\naudio2pose run --bad\n")
    assert check_block(wrong, tmp_path) != []


def test_inline_checker_refuses_an_unknown_verb_or_option():
    check_reference(["bag", "replay", "BAG", "[--rate", "R]", "[--topics", "...]"])
    with pytest.raises(AssertionError, match="no option --nope"):
        check_reference(["run", "--nope"])
    with pytest.raises(AssertionError, match="no such verb"):
        check_reference(["dataset"])
