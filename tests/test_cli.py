"""The command line: help, version, synth, and one clear line for bad input."""

import json
import subprocess
import sys

import pytest

from hortishape import __version__
from hortishape.cli import build_parser, main


def run(*args):
    return subprocess.run([sys.executable, "-m", "hortishape.cli", *args], capture_output=True, text=True)


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert "synth" in commands
    for name in commands:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        out = capsys.readouterr().out
        assert f"usage: hortishape {name}" in out
        assert "millimetres" in out


def test_synth_writes_meshes_with_ground_truth(tmp_path, capsys):
    out = tmp_path / "peppers"
    assert main(["synth", "pepper", "2", str(out), "--seed", "3", "--vertices", "8000", "--jobs", "1"]) == 0
    printed = capsys.readouterr().out
    assert "pepper_001" in printed and "wrote 2 pepper scans" in printed
    for i in range(2):
        assert (out / f"pepper_{i:03d}.ply").is_file()
        truth = json.loads((out / f"pepper_{i:03d}.truth.json").read_text())
        assert set(truth["landmarks"]) == {"stalk_tip", "bottom"}
        assert (out / f"pepper_{i:03d}.truth.npz").is_file()
    # nothing half-written is left behind
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_synth_family_and_its_error(tmp_path, capsys):
    assert main(["synth", "apple", "1", str(tmp_path / "a"), "--seed", "5", "--vertices", "4000",
                 "--family", "stalkless", "--jobs", "1"]) == 0
    truth = json.loads((tmp_path / "a" / "apple_000.truth.json").read_text())
    assert set(truth["landmarks"]) == {"stalk_tip", "bottom"}
    assert main(["synth", "apple", "1", str(tmp_path / "b"), "--family", "five-lobed"]) != 0
    assert "apple has no family 'five-lobed'" in capsys.readouterr().err


def test_synth_is_deterministic(tmp_path):
    for name in ("a", "b"):
        assert main(["synth", "apple", "1", str(tmp_path / name), "--seed", "5", "--vertices", "5000"]) == 0
    assert (tmp_path / "a" / "apple_000.ply").read_bytes() == (tmp_path / "b" / "apple_000.ply").read_bytes()


@pytest.mark.parametrize(
    "args, message",
    [
        (["synth", "kiwi", "2", "x"], "invalid choice"),
        (["synth", "apple", "0", "x"], "at least 1"),
        (["synth", "apple", "2", "x", "--noise", "-1"], "at least 0"),
        (["synth", "apple", "two", "x"], "whole number"),
    ],
)
def test_bad_arguments_exit_non_zero_with_one_message(args, message):
    result = run(*args)
    assert result.returncode != 0
    assert message in result.stderr
    assert "Traceback" not in result.stderr


def test_unwritable_output_is_one_clear_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    result = run("synth", "apple", "1", str(blocker / "out"), "--vertices", "3000")
    assert result.returncode == 1
    assert result.stderr.startswith("hortishape: error:")
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_register_command(tmp_path, capsys):
    scans = tmp_path / "scans"
    assert main(["synth", "pear", "2", str(scans), "--seed", "2", "--vertices", "10000", "--jobs", "1"]) == 0
    broken = tmp_path / "broken.obj"
    broken.write_text("v 0 0 0\n")
    out = tmp_path / "reg"
    code = main(["register", str(scans / "pear_000.ply"), str(scans / "pear_001.ply"), str(broken),
                 "--out", str(out), "--points", "2000", "--iterations", "10", "--jobs", "1"])
    captured = capsys.readouterr()
    assert code == 0  # one scan registered; the broken one reported and skipped
    assert "registered 1 of 2 scans" in captured.out
    assert "broken.obj" in captured.err
    assert (out / "pear_001.ply").is_file() and (out / "pear_001.json").is_file()
    # only bad targets: non-zero exit
    assert main(["register", str(scans / "pear_000.ply"), str(broken), "--out", str(out)]) == 1


def _subparsers():
    from hortishape.cli import _command_parsers

    return {name: command for name, (_, command) in _command_parsers(build_parser()).items()}


def test_help_says_each_default_once_and_none_on_required_options():
    for name, sub in _subparsers().items():
        for action in sub._actions:
            if not action.option_strings or action.help is None:
                continue
            text = sub._get_formatter()._get_help_string(action)
            assert text.lower().count("default") <= 1, (name, action.option_strings, text)
            assert "(default: None)" not in text and "(default: False)" not in text, (name, text)
            if action.required:
                assert "default" not in text.lower(), (name, action.option_strings, text)
    build = _subparsers()["build"].format_help()
    assert "(default: 50 1)" in build and "--out OUT" in build


def test_every_option_the_readme_and_the_docs_name_exists():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", root / "CONTRIBUTING.md",
             *(p for p in (root / "docs").rglob("*.md") if not {"_build", "tutorials", "api"} & set(p.parts))]
    commands = _subparsers()
    options = {name: {s for a in sub._actions for s in a.option_strings} for name, sub in commands.items()}
    # an option named alone may be a benchmark script's (the validation pages quote their arguments)
    scripts = "".join(path.read_text(encoding="utf-8") for path in (root / "benchmarks").glob("*.py"))
    from hortishape.cli import build_parser

    top = {s for a in build_parser()._actions for s in a.option_strings}  # hortishape --version
    top |= {"--durations"}  # pytest's, named where the docs say how long the tests take
    everywhere = set().union(top, *options.values(), re.findall(r'add_argument\(\s*"(--[a-z][a-z-]*)"', scripts))
    checked = 0
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for line in text.splitlines():
            # a command line: its options must be its command's
            m = re.match(r"^\s*(?:\.venv/bin/)?hortishape (\w+)(.*)", line)
            if m and m.group(1) in commands:
                for opt in re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", m.group(2).split("#")[0]):
                    assert opt in options[m.group(1)], (page.name, line, opt)
                    checked += 1
        # without the fenced blocks, whose three backticks would put the inline spans' pairing out of step
        for span in re.findall(r"`([^`]+)`", re.sub(r"```.*?```", "", text, flags=re.S)):
            if "\n" in span or span.startswith(("python ", "pip ", ".venv/bin/pip", "python3 ", "dask ", "sphinx")):
                continue  # code blocks (their hortishape lines are checked above), the benchmarks', pip's and dask's options
            words = span.split()
            if words and words[0] == "hortishape" and len(words) > 1 and words[1] in commands:
                names = options[words[1]]
            else:
                names = everywhere
            for opt in re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", span):
                assert opt in names, (page.name, span, opt)
                checked += 1
    assert checked > 100


def test_up_option_reaches_the_configuration_and_its_help_states_the_tolerance():
    from hortishape.cli import _registration_config
    from hortishape.registration.config import UP_TOLERANCE

    sub = _subparsers()["register"]
    assert f"{UP_TOLERANCE:g} degrees" in sub.format_help().replace("\n", " ").replace("  ", " ")
    args = sub.parse_args(["ref.ply", "a.ply", "--out", "o", "--up", "0", "0", "3"])
    assert _registration_config(args).up == (0.0, 0.0, 1.0)
    assert _registration_config(sub.parse_args(["ref.ply", "a.ply", "--out", "o"])).up is None


def test_tolerance_options_reach_the_configuration():
    from hortishape.cli import _registration_config

    sub = _subparsers()["register"]
    cfg = _registration_config(sub.parse_args(["ref.ply", "a.ply", "--out", "o", "--edge-tolerance", "0.005"]))
    assert (cfg.tolerance, cfg.edge_tolerance) == (1e-3, 0.005)
    assert _registration_config(sub.parse_args(["ref.ply", "a.ply", "--out", "o"])).edge_tolerance == 1e-3
    assert _registration_config(sub.parse_args(["ref.ply", "a.ply", "--out", "o"])).move_tolerance == 0.05
    moved = sub.parse_args(["ref.ply", "a.ply", "--out", "o", "--move-tolerance", "0"])
    assert _registration_config(moved).move_tolerance == 0.0
    assert _registration_config(moved).local_tail
    whole = sub.parse_args(["ref.ply", "a.ply", "--out", "o", "--whole-tail"])
    assert not _registration_config(whole).local_tail


def test_convert_and_sample_take_a_model_scalismo_wrote(tmp_path, capsys):
    from pathlib import Path

    import numpy as np

    from hortishape.model import ShapeModel
    from hortishape.statismo import model_format

    scalismo = Path(__file__).parent / "data" / "scalismo" / "asmData_model.h5"
    out = tmp_path / "model.json"
    assert main(["convert", str(scalismo), str(out)]) == 0
    assert "1400 points, 2800 triangles, 50 modes" in capsys.readouterr().out
    assert model_format(out) == "json"
    assert main(["convert", str(out), str(tmp_path / "again.bin"), "--format", "hdf5"]) == 0
    np.testing.assert_array_equal(ShapeModel.load(tmp_path / "again.bin").components_,
                                  ShapeModel.load(scalismo).components_)
    assert main(["sample", str(out), "2", "--out", str(tmp_path / "s"), "--seed", "1", "--no-picture"]) == 0
    assert len(list((tmp_path / "s").glob("sample_*.ply"))) == 2
    # a point-set model: said plainly, no traceback
    ShapeModel().fit(np.random.default_rng(0).normal(size=(5, 8, 3))).save(tmp_path / "points.h5")
    capsys.readouterr()
    assert main(["sample", str(tmp_path / "points.h5"), "2", "--out", str(tmp_path / "p")]) == 1
    assert "point-set model (no triangles)" in capsys.readouterr().err


def test_a_warning_is_one_hortishape_line_without_python_s_file_and_line(monkeypatch, capsys):
    import warnings

    from hortishape import cli

    def run(args):
        warnings.warn("scan.tif: a voxel size\n    from the log", UserWarning)
        return 0

    monkeypatch.setattr(cli, "_run_convert", run)
    assert cli.main(["convert", "model.h5", "out.h5"]) == 0
    assert capsys.readouterr().err == "hortishape: warning: scan.tif: a voxel size from the log\n"
    assert warnings.showwarning is not cli._show_warning  # put back after the command
