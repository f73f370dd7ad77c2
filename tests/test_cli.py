"""The command line as a whole (issues 12 and 13): one configuration loader for every
command, a parser that imports nothing heavy, and help texts that are complete and plain."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from tcm_companion import cli
from tcm_companion.cli import common

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "tests" / "data" / "examples" / "EX-T90"

#: What building the parser, or any command's --help, must not import (each costs from
#: tens of milliseconds to 0.4 s: the generated MAVLink dialect alone is ~0.37 s).
HEAVY = (
    "numpy",
    "cv2",
    "scipy",
    "matplotlib",
    "mcap",
    "tqdm",
    "pymavlink",
    "uvloop",
    "tcm_companion.mavlink.tcm_dialect",
    "tcm_companion.config",
    "tcm_companion.core",
)

#: The commands that read the configuration, with the arguments each needs besides it.
CONFIG_COMMANDS = {
    "run": ["run"],
    "sitl": ["sitl"],
    "replay": ["replay", "SCENARIO", "--results", "r.csv"],
    "eval": ["eval", "SCENARIO"],
    "demo": ["demo"],
    "bench": ["bench"],
    "import": ["import", "SCENARIO", "--log", "x.mcap", "--results"],
    "plot": ["plot", "SCENARIO"],
}


def _subparsers(parser: argparse.ArgumentParser) -> list[argparse._SubParsersAction[Any]]:
    return [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]


def _walk(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every parser under ``parser`` with its command path (``("sim", "export")``)."""
    out = [(path, parser)]
    for action in _subparsers(parser):
        for name, child in action.choices.items():
            out += _walk(child, (*path, name))
    return out


# -- import cost -------------------------------------------------------------------------
@pytest.mark.slow  # a subprocess
def test_building_the_parser_and_help_import_nothing_heavy() -> None:
    """``-X importtime`` lists every module imported; none of HEAVY may be among them,
    for the parser and for every command's --help (a test that fails, not a timing)."""
    script = textwrap.dedent(
        """
        import contextlib, io
        import tcm_companion.cli as c
        parser = c.build_parser()
        for argv in (["--help"], ["run", "--help"], ["sitl", "--help"], ["replay", "--help"],
                     ["eval", "--help"], ["demo", "--help"], ["bench", "--help"],
                     ["export", "--help"], ["import", "--help"], ["plot", "--help"],
                     ["config", "check", "--help"], ["sim", "export", "--help"],
                     ["sim", "list", "--help"], ["mock-autopilot", "--help"]):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                c.build_parser().parse_args(argv)
        """
    )
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", script],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    imported = {
        line.rsplit("|", 1)[1].strip()
        for line in proc.stderr.splitlines()
        if line.startswith("import time:") and "|" in line
    }
    assert "tcm_companion.cli" in imported  # the listing is what we think it is
    heavy = [h for h in HEAVY if any(m == h or m.startswith(h + ".") for m in imported)]
    assert heavy == [], f"building the parser imported {heavy}"


def test_choices_are_the_core_s() -> None:
    """The parser's light copies of the core's and the simulator's names."""
    from tcm_companion.core.classify import METHODS
    from tcm_companion.sim.scene import cameras, names, scenarios

    assert common.METHODS == METHODS
    assert common.CAMERA_PRESETS == cameras.PRESETS
    assert scenarios.SCENARIO_NAMES is names.SCENARIO_NAMES
    assert scenarios.PAPER_SCENARIO_NAMES is names.PAPER_SCENARIO_NAMES
    assert scenarios.OBJECT_SCENARIO_NAMES is names.OBJECT_SCENARIO_NAMES
    for name in names.SCENARIO_NAMES:
        assert scenarios.describe_scenario(name)  # each name has a design


# -- help texts ----------------------------------------------------------------------------
def test_every_option_has_a_plain_help() -> None:
    """Every argument of every command has a help text, and nothing --help shows carries
    reStructuredText markup (double backticks)."""
    missing: list[str] = []
    for path, parser in _walk(cli.build_parser()):
        where = " ".join(("tcm-companion", *path))
        assert parser.description, f"{where}: no description"
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue  # its commands are parsers of their own, checked in turn
            if not action.help or action.help == argparse.SUPPRESS:
                missing.append(f"{where} {'/'.join(action.option_strings) or action.dest}")
        text = parser.format_help()
        assert "``" not in text, f"{where} --help shows RST markup"
    assert missing == [], f"options without help: {missing}"


def test_the_description_lists_every_command() -> None:
    parser = cli.build_parser()
    description = parser.description or ""
    commands = [" ".join(path) for path, p in _walk(parser) if path and not _subparsers(p)]
    assert len(commands) >= 13
    for name in (
        "demo",
        "sitl",
        "run",
        "config check",
        "plot",
        "export",
        "import",
        "sim export",
        "sim list",
        "mock-autopilot",
        "bench",
        "eval",
        "replay",
    ):
        assert name in commands
    for name in commands:
        assert f"\n  {name} " in description, f"{name} is not in tcm-companion --help"


def test_the_readme_lists_every_command_and_option() -> None:
    """README's Commands block shows each command with all its options (--config and
    --set are in the sentence under it, which says every command takes them)."""
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Commands") :]
    start = section.index("```sh\n") + 6
    end = section.index("\n```", start)
    block = section[start:end]
    usage: dict[str, str] = {}
    current = ""
    for line in block.splitlines():
        if line.startswith("tcm-companion "):
            words = line.split()[1:3]
            two = " ".join(words)
            current = two if two in ("sim export", "sim list", "config check") else words[0]
        usage[current] = usage.get(current, "") + " " + line
    prose = section[end : section.index("\n- **")]
    assert "--config FILE" in prose and "--set TABLE.KEY=VALUE" in prose
    assert "TCM_COMPANION__TABLE__KEY" in prose
    for path, parser in _walk(cli.build_parser()):
        if not path or _subparsers(parser):
            continue
        name = " ".join(path)
        assert name in usage, f"README's Commands do not show {name}"
        for action in parser._actions:
            opts = action.option_strings
            if opts and not {"--help", "--config", "--set"} & set(opts):
                assert any(o in usage[name] for o in opts), f"README: {name} lacks {opts}"


@pytest.mark.slow  # a subprocess
def test_python_m_and_version() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "tcm_companion", "--version"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert proc.returncode == 0 and proc.stdout.strip()


# -- one configuration loader --------------------------------------------------------------
@pytest.mark.parametrize("command", sorted(CONFIG_COMMANDS))
def test_every_command_reads_the_configuration_the_same_way(
    command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--set > environment > --config file > defaults, for every command that uses it."""
    monkeypatch.chdir(tmp_path)  # no ./config.toml
    for name in list(os.environ):
        if name.startswith("TCM_COMPANION__"):
            monkeypatch.delenv(name)
    parser = cli.build_parser()
    argv = CONFIG_COMMANDS[command]

    def seed(*extra: str) -> int:
        args = parser.parse_args([*argv, *extra])
        return cli.config_from_args(args).sim.seed

    assert seed() == 0  # built-in default
    (tmp_path / "config.toml").write_text("[sim]\nseed = 1\n")
    assert seed() == 1  # ./config.toml when --config is not given
    other = tmp_path / "other.toml"
    other.write_text("[sim]\nseed = 2\n")
    assert seed("--config", str(other)) == 2
    monkeypatch.setenv("TCM_COMPANION__SIM__SEED", "3")
    assert seed("--config", str(other)) == 3
    assert seed("--config", str(other), "--set", "sim.seed=4") == 4


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("command", sorted(CONFIG_COMMANDS))
@pytest.mark.parametrize("how", ["environment", "--set", "--config"])
def test_every_command_refuses_a_bad_configuration(
    command: str,
    how: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The command itself loads through the one loader: a bad value from any source is a
    "config error" (exit 2), before any work and without output files."""
    monkeypatch.chdir(tmp_path)
    argv = [str(EXAMPLE) if a == "SCENARIO" else a for a in CONFIG_COMMANDS[command]]
    if command in ("eval", "demo", "plot"):
        argv += ["--out", str(tmp_path / "out")]
    if how == "environment":
        monkeypatch.setenv("TCM_COMPANION__SIM__SEED", "abc")
    elif how == "--set":
        argv += ["--set", "sim.seed=abc"]
    else:
        argv += ["--config", str(tmp_path / "missing.toml")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("config error: "), err
    assert {
        "environment": "TCM_COMPANION__SIM__SEED",
        "--set": "--set sim.seed",
        "--config": "missing.toml: no such file",
    }[how] in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


def test_config_check_takes_the_environment_and_set(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    p = tmp_path / "c.toml"
    p.write_text("[sim]\nseed = 1\n")
    monkeypatch.setenv("TCM_COMPANION__SIM__SEED", "3")
    assert cli.main(["config", "check", str(p)]) == 0
    assert "seed = 3" in capsys.readouterr().out
    assert cli.main(["config", "check", str(p), "--set", "sim.seed=5"]) == 0
    assert "seed = 5" in capsys.readouterr().out
    p.write_text("[sim]\nseed = 'x'\n")
    monkeypatch.delenv("TCM_COMPANION__SIM__SEED")
    assert cli.main(["config", "check", str(p)]) == 2
    assert capsys.readouterr().err.startswith(f"config error: {p}")


def test_bench_daemon_refuses_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["bench", "--daemon", "--config", "x.toml"]) == 2
    assert "--set" in capsys.readouterr().err


def test_an_os_error_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "r.csv"  # a file where a directory should be
    assert cli.main(["replay", str(EXAMPLE), "--results", str(out), "-q"]) == 2
    assert capsys.readouterr().err.startswith("error: ")


# -- eval's plots ----------------------------------------------------------------------------
@pytest.mark.slow
def test_eval_writes_its_plots_to_a_default_folder_and_says_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(["eval", str(EXAMPLE), "--no-bsm", "-q"]) == 0
    out = capsys.readouterr().out
    assert "plots written to out/eval/" in out
    assert (tmp_path / "out" / "eval" / "roc_native.png").stat().st_size > 1000
    assert (tmp_path / "out" / "eval" / "report.txt").is_file()
