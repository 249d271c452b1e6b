"""One meaning per option name across commands: the renamed options' old spellings still work
for one version and say so on stderr; the new spellings print nothing."""

import re

import click
import pytest

from benchmark.cli import main
from benchmark.commands import old_spelling
from tests.benchmark.results.helpers import record, write


def notice(old, new):
    return f"trase-bench: {old} is now {new} (the old spelling goes in the next version)\n"


# (command, the arguments it needs to get past parsing, old spelling, new spelling, a value or None for a flag)
RENAMED = [
    ("run", ["--method", "trase", "--dataset", "hypernerf"], "--out", "--runs", "x"),
    ("ablate", ["smoothing", "--dataset", "hypernerf"], "--out", "--runs", "x"),
    ("figures", [], "--out", "--runs", "x"),
    ("figures", [], "--format", "--dataset", "hypernerf"),
    ("runs", [], "--results", "--runs", "x"),
    ("leaderboard", [], "--results", "--runs", "x"),
    ("report", [], "--out", "--runs", "x"),
    ("masks", ["--dataset", "hypernerf"], "--no-progress", "--quiet", None),
]


def _toy():
    @click.command()
    @old_spelling("--results", "--runs")
    @old_spelling("--no-progress", "--quiet")
    @old_spelling("--format", "--dataset")
    @click.option("--runs", "runs_dir", default="runs", show_default=True, help="The folder of runs.")
    @click.option("--quiet", is_flag=True, help="No progress output.")
    @click.option("--dataset", "datasets", multiple=True, help="Repeatable.")
    def toy(runs_dir, quiet, datasets):
        """A toy command."""
        click.echo(f"{runs_dir} {quiet} {','.join(datasets)}")

    return toy


def _call(cmd, args, capsys):
    try:
        cmd.main(args, prog_name="toy", standalone_mode=False)
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code, capsys.readouterr()
    return 0, capsys.readouterr()


def test_old_spellings_stand_for_the_new_ones(capsys):
    toy = _toy()
    rc, got = _call(toy, ["--runs", "a", "--quiet", "--dataset", "d1", "--dataset", "d2"], capsys)
    assert rc == 0 and got.out == "a True d1,d2\n" and got.err == ""
    rc, got = _call(toy, ["--results=a", "--no-progress", "--format", "d1", "--format", "d2"], capsys)
    assert rc == 0 and got.out == "a True d1,d2\n"
    assert got.err == notice("--results", "--runs") + notice("--no-progress", "--quiet") + \
        notice("--format", "--dataset")
    rc, got = _call(toy, [], capsys)
    assert rc == 0 and got.out == "runs False \n" and got.err == ""
    # both spellings at once: a usage error, not a silent choice
    rc, got = _call(toy, ["--results", "a", "--runs", "b"], capsys)
    assert rc == 2 and "--results is the old spelling of --runs; give --runs only" in got.err
    # the help shows only the new spelling
    rc, got = _call(toy, ["--help"], capsys)
    assert "--runs" in got.out and "--results" not in got.out and "--no-progress" not in got.out


def test_old_spelling_needs_the_option_it_renames():
    with pytest.raises(TypeError, match="declare the option --runs"):
        old_spelling("--results", "--runs")(lambda runs_dir: None)


@pytest.mark.parametrize("command,args,old,new,value", RENAMED, ids=[f"{r[0]} {r[2]}" for r in RENAMED])
def test_each_renamed_option(command, args, old, new, value, capsys):
    # the help lists only the new spelling
    assert main([command, "--help"]) == 0
    text = capsys.readouterr().out
    assert re.search(re.escape(new) + r"(?![\w-])", text)
    assert not re.search(re.escape(old) + r"(?![\w-])", text)
    # the old spelling is declared: with the new one beside it, the command stops before doing anything
    given = [] if value is None else [value]
    assert main([command, *args, old, *given, new, *given]) == 2
    assert f"{old} is the old spelling of {new}" in capsys.readouterr().err


def test_runs_and_leaderboard_read_the_folder_of_runs_under_either_spelling(tmp_path, capsys):
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.9, 0.99))
    for command, extra in (("runs", []), ("leaderboard", ["--variant", "synthetic"])):
        assert main([command, "--runs", str(tmp_path), *extra]) == 0
        new = capsys.readouterr()
        assert "trase" in new.out and new.err == ""
        assert main([command, "--results", str(tmp_path), *extra]) == 0
        old = capsys.readouterr()
        assert old.out == new.out and old.err == notice("--results", "--runs")
