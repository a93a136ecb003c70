"""The examples of README.md and docs/*.md work as written.

Every fenced ``bash`` and ``python`` block of those pages runs, page by page and in page order, in
a fresh copy of the working folder that the setup block of docs/commands.md makes (a small
synthetic room with its map), and must succeed. A block that needs what a test cannot have
(network, GPU, real data, a Ray cluster, long runs, ``make install``) carries
``<!-- not run: REASON -->`` on the line before its fence, and must say why. ``ldlmap`` and
``ldlloc`` command lines run in this process through Typer's ``CliRunner`` (one import of torch
for all of them), any other line through bash, where ``ldlmap`` and ``ldlloc`` are this
checkout's programs. Also checked: every relative link and anchor of those pages resolves, and
docs/commands.md has an example of every command and option of both programs.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = pytest.mark.xdist_group("docs")

REPO = Path(__file__).resolve().parents[1]
PROGRAMS = ("ldlmap", "ldlloc")
RUN_LANGUAGES = ("bash", "python")
OTHER_LANGUAGES = ("", "text", "toml", "json")  # shown, never run
MARKER = re.compile(r"^<!--\s*(not run|setup):\s*(.*?)\s*-->$")
FENCE = re.compile(r"^```([\w+-]*)\s*$")
HEREDOC = re.compile(r"<<-?\s*['\"]?(\w+)['\"]?")


def doc_pages() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    language: str
    code: str
    marker: str | None  # "not run", "setup" or None
    reason: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def fenced_blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a Markdown page, each with the marker on the line before it."""
    lines = page.read_text(encoding="utf-8").splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and lines[j].strip() != "```":
            j += 1
        assert j < len(lines), f"{page.name}:{i + 1}: unclosed code fence"
        before = lines[i - 1].strip() if i > 0 else ""
        mk = MARKER.match(before)
        blocks.append(Block(page, i + 1, m.group(1), "\n".join(lines[i + 1:j]) + "\n",
                            mk.group(1) if mk else None, mk.group(2) if mk else ""))
        i = j + 1
    return blocks


def all_blocks() -> list[Block]:
    return [b for page in doc_pages() for b in fenced_blocks(page)]


def setup_block() -> Block:
    found = [b for b in all_blocks() if b.marker == "setup"]
    assert len(found) == 1, f"expected one setup block, found {[b.where for b in found]}"
    return found[0]


def shell_commands(code: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, heredocs kept with their command,
    comment-only and blank lines dropped."""
    lines, out, i = code.splitlines(), [], 0
    while i < len(lines):
        cmd = lines[i]
        while cmd.endswith("\\") and i + 1 < len(lines):
            i += 1
            cmd = cmd[:-1] + " " + lines[i].strip()
        m = HEREDOC.search(cmd)
        if m:  # the heredoc's body, up to its terminator, belongs to this command
            body = []
            while i + 1 < len(lines):
                i += 1
                body.append(lines[i])
                if lines[i].strip() == m.group(1):
                    break
            cmd = "\n".join([cmd, *body])
        i += 1
        if cmd.strip() and not cmd.strip().startswith("#"):
            out.append(cmd)
    return out


def needs_shell(cmd: str) -> bool:
    """True when a command line uses more of bash than words (operators, redirections, expansions)."""
    if "\n" in cmd or "$" in cmd or "`" in cmd:
        return True
    lexer = shlex.shlex(cmd, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    return any(tok and set(tok) <= set("();<>|&") for tok in lexer)


@pytest.fixture(scope="session")
def program_bin(tmp_path_factory) -> Path:
    """A folder whose ``ldlmap`` and ``ldlloc`` run this checkout's code with this interpreter."""
    folder = tmp_path_factory.mktemp("docs_bin")
    for name in PROGRAMS:
        script = folder / name
        script.write_text(f'#!/bin/sh\nPYTHONPATH="{REPO}${{PYTHONPATH:+:$PYTHONPATH}}" '
                          f'exec "{sys.executable}" -m {name}.cli "$@"\n')
        script.chmod(0o755)
    return folder


class Runner:
    """Runs a page's blocks in one working folder, as a reader following the page would."""

    def __init__(self, cwd: Path, bin_dir: Path):
        self.cwd = cwd
        self.env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
                    "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
        self.namespace: dict = {"__name__": "__main__"}  # the page's Python blocks share it, like a notebook

    def run_block(self, block: Block) -> None:
        if block.language == "python":
            self._python(block)
        else:
            for cmd in shell_commands(block.code):
                self._command(cmd, block)

    def _command(self, cmd: str, block: Block) -> None:
        words = [] if needs_shell(cmd) else shlex.split(cmd, comments=True)
        if words and words[0] in PROGRAMS:
            self._in_process(words, block)
        elif words and words[0] == "cd":
            self.cwd = (self.cwd / words[1]).resolve()
        else:
            done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", cmd], cwd=self.cwd, env=self.env,
                                  capture_output=True, text=True, timeout=600)
            assert done.returncode == 0, (f"{block.where}: `{cmd}` exited with {done.returncode}\n"
                                          f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}")

    def _in_process(self, words: list[str], block: Block) -> None:
        from typer.testing import CliRunner

        if words[0] == "ldlmap":
            from ldlmap.cli import app
        else:
            from ldlloc.cli import app
        old = Path.cwd()
        os.chdir(self.cwd)
        try:
            res = CliRunner().invoke(app, words[1:])
        finally:
            os.chdir(old)
        assert res.exit_code == 0, (f"{block.where}: `{shlex.join(words)}` exited with {res.exit_code}\n"
                                    f"{res.output[-4000:]}\n{res.exception!r}")

    def _python(self, block: Block) -> None:
        old = Path.cwd()
        os.chdir(self.cwd)
        try:
            exec(compile(block.code, block.where, "exec"), self.namespace)
        finally:
            os.chdir(old)


@pytest.fixture(scope="session")
def working_folder(tmp_path_factory, program_bin) -> Path:
    """The folder that the setup block of docs/commands.md makes."""
    folder = tmp_path_factory.mktemp("docs_setup")
    Runner(folder, program_bin).run_block(setup_block())
    return folder


def test_code_blocks_are_run_or_say_why_not():
    blocks = all_blocks()
    assert any(b.language in RUN_LANGUAGES and b.marker is None for b in blocks)
    setup_block()
    for b in blocks:
        assert b.language in RUN_LANGUAGES + OTHER_LANGUAGES, f"{b.where}: unknown code language {b.language!r}"
        if b.marker == "not run":
            assert b.language in RUN_LANGUAGES, f"{b.where}: only bash and python blocks are run"
            assert len(b.reason.split()) >= 3, f"{b.where}: a block that is not run must say why"


def test_shell_commands_split_like_bash():
    code = "# a comment\nldlmap info a.h5  # why\nldlmap build x.ply \\\n  -o y.h5\ncat > f <<'EOF'\nk = 1\nEOF\n\n"
    assert shell_commands(code) == ["ldlmap info a.h5  # why", "ldlmap build x.ply  -o y.h5",
                                    "cat > f <<'EOF'\nk = 1\nEOF"]
    assert not needs_shell("ldlmap info 'a b.h5'  # comment")
    assert needs_shell("mkdir -p a && cp b a/") and needs_shell("ls *.jpg | head") and needs_shell("echo $HOME")


def runnable(page: Path) -> list[Block]:
    return [b for b in fenced_blocks(page) if b.language in RUN_LANGUAGES and b.marker is None]


OUTPUT_OPTIONS = ("-o", "--output", "--html", "--save-vis")  # what a command writes, beside `synth OUT`


def taken_outputs(code: str, cwd: Path) -> list[str]:
    """The outputs that the ``ldlmap``/``ldlloc`` lines of a bash block would write but that ``cwd``
    already holds, so the block would fail or mix with earlier results there: ``synth OUT`` into a
    non-empty folder, an existing ``-o``/``--output``/``--html``/``--save-vis`` path; lines with
    ``--overwrite`` or ``--resume`` mean to reuse them."""
    taken = []
    for cmd in shell_commands(code):
        words = [] if needs_shell(cmd) else shlex.split(cmd, comments=True)
        if len(words) < 3 or words[0] not in PROGRAMS or {"--overwrite", "--resume"} & set(words):
            continue
        outs = [words[2]] if words[:2] == ["ldlmap", "synth"] else []
        outs += [words[i + 1] for i, w in enumerate(words[:-1]) if w in OUTPUT_OPTIONS]
        for out in outs:
            p = cwd / out
            if p.is_file() or (p.is_dir() and any(p.iterdir())):
                taken.append(f"`{cmd}`: {out} is already there")
    return taken


def test_taken_outputs_names_what_a_block_would_collide_with(tmp_path):
    (tmp_path / "data" / "synth").mkdir(parents=True)
    (tmp_path / "data" / "synth" / "dataset.json").write_text("{}")
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "all.json").write_text("{}")
    code = ("ldlmap synth data/synth --preset demo\nldlmap synth data/new\n"
            "ldlloc run --root data/synth --output results/all.json\n"
            "ldlloc run --root data/synth --output results/all.json --resume\n"
            "ldlloc report results/all.json --html report.html\n")
    assert taken_outputs(code, tmp_path) == ["`ldlmap synth data/synth --preset demo`: data/synth is already there",
                                             "`ldlloc run --root data/synth --output results/all.json`: "
                                             "results/all.json is already there"]


@pytest.mark.parametrize("page", [p.relative_to(REPO).as_posix() for p in doc_pages() if runnable(p)])
def test_examples_run(page, working_folder, program_bin, tmp_path):
    """The page's blocks in order, as a reader follows them; a block that is not run must still
    fit there: it would not collide with what the working folder and the blocks before it hold."""
    folder = tmp_path / "work"
    shutil.copytree(working_folder, folder)
    runner = Runner(folder, program_bin)
    for block in fenced_blocks(REPO / page):
        if block.language in RUN_LANGUAGES and block.marker is None:
            runner.run_block(block)
        elif block.language == "bash" and block.marker == "not run":
            assert not taken_outputs(block.code, runner.cwd), (block.where, taken_outputs(block.code, runner.cwd))


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
    headings = {_slug(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", text, flags=re.M)}
    return headings | set(re.findall(r'<a id="([^"]+)"></a>', text))


def test_code_comments_point_at_existing_measurements():
    """The code's ``docs/measurements.md#anchor`` pointers name entries that exist."""
    anchors = _anchors(REPO / "docs" / "measurements.md")
    refs = [(p, a) for p in sorted((REPO / "ldlmap").rglob("*.py")) + sorted((REPO / "ldlloc").rglob("*.py"))
            for a in re.findall(r"docs/measurements\.md#([\w-]+)", p.read_text(encoding="utf-8"))]
    assert len(refs) >= 20
    missing = [f"{p.relative_to(REPO)}: #{a}" for p, a in refs if a not in anchors]
    assert not missing, missing


def test_relative_links_resolve():
    link = re.compile(r"\]\(([^)\s]+)\)")
    checked = 0
    for page in doc_pages():
        text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
        for target in link.findall(text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            assert dest.exists(), f"{page.relative_to(REPO)}: broken link {target}"
            if anchor and dest.suffix == ".md":
                assert anchor in _anchors(dest), f"{page.relative_to(REPO)}: no heading for #{anchor} in {target}"
            checked += 1
    assert checked > 10


def test_every_command_and_option_has_an_example():
    """docs/commands.md shows every command of both programs with each of its options."""
    import typer.main

    from ldlloc.cli import app as loc_app
    from ldlmap.cli import app as map_app

    used: dict[tuple[str, str], set[str]] = {}
    for block in fenced_blocks(REPO / "docs" / "commands.md"):
        if block.language != "bash":
            continue
        for cmd in shell_commands(block.code):
            for part in re.split(r"&&|;|\|", cmd):
                try:
                    words = shlex.split(part, comments=True)
                except ValueError:
                    continue
                if len(words) >= 2 and words[0] in PROGRAMS:
                    used.setdefault((words[0], words[1]), set()).update(w.split("=")[0] for w in words[2:])
    for program, app in (("ldlmap", map_app), ("ldlloc", loc_app)):
        group = typer.main.get_command(app)
        for name, command in group.commands.items():
            assert (program, name) in used, f"docs/commands.md has no example of `{program} {name}`"
            for param in command.params:
                names = [o for o in param.opts + param.secondary_opts if o.startswith("-")]
                if not names or "--help" in names:
                    continue
                assert used[(program, name)] & set(names), f"docs/commands.md: no example of `{program} {name} {names[0]}`"
