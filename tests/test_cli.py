"""The command line as an operator meets it: exit codes, one-line errors, files written or not at all."""

import json
import re
import shutil
import subprocess
import sys

import click
import pytest
import trimesh

from hlr_lab.cli.main import main
from hlr_lab.formats.plan import read_plan
from hlr_lab.object.procedural import pebble
from tests.renderer_guard import require_aravis, require_renderer


def run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_segment_then_plan_on_the_builtin_object(capsys, tmp_path):
    regions = tmp_path / "regions.json"
    code, _, err = run(capsys, "segment", "--mesh", "builtin:pebble", "-o", str(regions))
    assert code == 0, err
    assert "4 regions" in err
    plan = tmp_path / "plan.json"
    code, _, err = run(
        capsys,
        "plan",
        "--mesh",
        "builtin:pebble",
        "--regions",
        str(regions),
        "--sim",
        "--spacing",
        "1",
        "-o",
        str(plan),
    )
    assert code == 0, err
    assert "coverage" in err
    said = re.search(r"(\d+) lights; lower bound (\d+) \(LP [\d.]+\); optimum (proven|not proven)", err)
    assert said, err
    assert "chosen by:" in err
    p = read_plan(plan)
    assert p.poses
    assert all(c.satisfied for c in p.coverage.values())
    assert p.parameters.criterion == "capped"
    assert p.summary is not None
    assert p.summary.lights_by_criterion is not None
    assert len(p.poses) <= min(p.summary.lights_by_criterion.values())  # never more than either greedy
    assert int(said.group(1)) == len(p.poses)
    assert int(said.group(2)) == p.summary.lower_bound
    assert p.summary.lower_bound is not None
    assert p.summary.lower_bound <= len(p.poses)
    assert p.summary.chosen_by in {"greedy (capped)", "greedy (plain)", "integer programme"}


def test_uncovered_regions_give_exit_status_3_and_a_written_plan(capsys, tmp_path):
    plan = tmp_path / "plan.json"
    code, _, err = run(
        capsys, "plan", "--mesh", "builtin:pebble", "--sim", "--views", "0", "--spacing", "1", "-o", str(plan)
    )
    assert code == 3
    assert "not visible" in err
    uncovered = json.loads(plan.read_text())["uncovered"]
    assert uncovered
    assert uncovered[0]["reason"].startswith("not visible")


def test_plan_a_vertex_coloured_ply_with_a_fixed_region_count(capsys, tmp_path):
    m = pebble(subdivisions=3).mesh
    ply = tmp_path / "pebble.ply"
    trimesh.Trimesh(m.vertices, m.faces, vertex_colors=m.vertex_colours, process=False).export(ply)
    regions = tmp_path / "regions.json"
    code, _, err = run(capsys, "segment", "--mesh", str(ply), "--regions", "3", "-o", str(regions))
    assert code == 0, err
    data = json.loads(regions.read_text())
    assert len(data["regions"]) == 3
    assert data["mesh"] == "pebble.ply"
    code, _, err = run(
        capsys,
        "plan",
        "--mesh",
        str(ply),
        "--regions",
        str(regions),
        "--sim",
        "--count",
        "vertices",
        "--min-samples",
        "10",
        "--spacing",
        "1",
        "-o",
        str(tmp_path / "plan.json"),
    )
    assert code in (0, 3), err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["plan", "--mesh", "missing.ply", "--sim"], "missing.ply: no such mesh file"),
        (["plan", "--mesh", "builtin:pebble"], "which rig?"),
        (["plan", "--mesh", "builtin:pebble", "--sim", "--views", "0,east"], "--views"),
        (["plan", "--mesh", "builtin:cube", "--sim"], "unknown built-in object"),
        (["plan", "--mesh", "builtin:pebble", "--rig", "nowhere.toml"], "nowhere.toml: no such file"),
        (["plan", "--mesh", "builtin:pebble", "--sim", "--sphere-scale", "0.5"], "--sphere-scale"),
    ],
)
def test_errors_are_one_clear_line_and_write_nothing(capsys, tmp_path, args, message):
    out_file = tmp_path / "plan.json"
    code, _, err = run(capsys, *args, "-o", str(out_file))
    assert code == 1
    assert message in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out_file.exists()


def test_debug_shows_the_traceback(capsys, tmp_path):
    code, _, err = run(
        capsys, "--debug", "plan", "--mesh", "missing.ply", "--sim", "-o", str(tmp_path / "p.json")
    )
    assert code == 1
    assert "Traceback" in err


@pytest.mark.parametrize(
    "command",
    [
        ["segment"],
        ["plan"],
        ["export"],
        ["bench", "plan"],
        ["bench", "fit"],
        ["bench", "sim"],
        ["bench", "acquire"],
        ["bench", "session-fit"],
        ["fit"],
        ["sim", "serve"],
        ["acquire"],
        ["doctor"],
    ],
)
def test_every_command_has_help_with_an_example(capsys, command):
    code, out, _ = run(capsys, *command, "--help")
    assert code == 0
    assert "Example" in out


def test_usage_errors_exit_2_with_one_line_naming_the_option(capsys):
    for args, said in ((("plan", "--theta-c", "-3"), "--theta-c"), (("segment", "--delta-e", "nan"), "--delta-e"),
                       (("plan", "--nope"), "--nope"), (("sgment",), "No such command 'sgment'")):  # fmt: skip
        code, _, err = run(capsys, *args)
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith("error: ")
        assert said in lines[0]
        assert "--help" in lines[0]


def test_console_script_runs_as_a_process(tmp_path):
    exe = shutil.which("hlr-lab")
    cmd = [exe] if exe else [sys.executable, "-m", "hlr_lab.cli.main"]
    proc = subprocess.run(
        [*cmd, "plan", "--mesh", "missing.obj", "--sim", "-o", str(tmp_path / "p.json")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1
    assert "no such mesh file" in proc.stderr


@pytest.mark.slow
def test_plan_benchmark_prints_figures(capsys):
    code, out, err = run(capsys, "bench", "plan", "--large", "0", "--no-fewest")
    assert code == 0, err
    assert "builtin:pebble" in out
    assert "plan time" in out
    assert "lower bound" in out
    assert "peak RSS" in out
    assert "measured max nearest-neighbour" in err


def test_sim_benchmark_prints_figures(capsys):
    require_aravis()
    code, out, err = run(capsys, "bench", "sim", "-n", "20", "--frames", "0")
    assert code == 0, err
    assert "ping" in out
    assert "median" in out
    # the camera's frames through GigE Vision, and the lost packets resent (none missing, every frame whole)
    lost = re.search(r"Mono16, 5% of packets lost\s+(\d+) / (\d+) / (\d+); (\d+) of (\d+)", out)
    assert lost, out
    received, resent, missing, whole, frames = map(int, lost.groups())
    assert received > 0
    assert 0.02 * received < resent < 0.1 * received
    assert (missing, whole) == (0, frames)


def test_acquire_benchmark_prints_figures(capsys):
    """The figures printed, and the camera's link over the whole run: with 5 % of its stream packets lost
    on their first sending, each is resent (about 5 % of those received) and none is missing; every frame is
    stored whole."""
    require_renderer()
    code, out, err = run(capsys, "bench", "acquire", "--poses", "3", "--packet-loss", "0.05")
    assert code == 0, err
    assert "3 poses, 9 frames" in out
    packets = re.search(r"received / resent / missing ([\d,]+) / ([\d,]+) / ([\d,]+)", out)
    assert packets, out
    received, resent, missing = (int(g.replace(",", "")) for g in packets.groups())
    assert received >= 9 * 800  # a 1280×960×3 16-bit frame is ~830 packets of ~9000 bytes
    assert resent >= 0.04 * received  # 5 % lost, less the draw's spread over ~7 500 packets (σ ≈ 0.25 %)
    assert missing == 0
    overhead = re.search(r"overhead per pose .*: median ([\d.]+) ms", out)
    assert overhead
    assert 0 < float(overhead[1]) < 1000
    counts = re.search(r"transactions per pose, median: servo (\d+), Modbus (\d+)", out)
    assert counts
    # a move and its settling take several servo sync reads, and the stage its start and status reads
    assert int(counts[1]) >= 3
    assert int(counts[2]) >= 4


def test_session_fit_benchmark_prints_figures(capsys):
    require_renderer()
    code, out, err = run(capsys, "bench", "session-fit", "--poses", "2")
    assert code == 0, err
    assert "session: 2 poses, 6 frames" in out
    assert re.search(r"fit \(target .*\): [\d.]+ s, peak RSS \d+ MB; 4 regions measured", out)
    for stage in ("hdr", "g-buffer", "selection", "shadows", "fitting"):
        assert f"{stage} " in out


def test_materials_benchmark_compares_every_parameter_with_its_truth(capsys, tmp_path):
    """One pebble scene with held-out materials: a line for the scene, the coverage table, and the results
    file, whose every parameter is the fit's against the scene's truth (within 2 % here: the pebble is
    the easy object)."""
    require_renderer()
    code, out, err = run(capsys, "bench", "materials", "--scenes", "1", "--out", str(tmp_path / "b"))
    assert code == 0, err
    assert re.search(r"scene +0 pebble *: worst rd +[\d.]+ %", out), out
    assert re.search(r"^rd +12 ", out, re.M), out  # four regions, three channels each
    results = json.loads((tmp_path / "b" / "materials-bench.json").read_text())
    truth = json.loads((tmp_path / "b" / "scene-000-pebble" / "truth.json").read_text())
    assert {p["parameter"] for p in results["parameters"]} == {"rd", "rs", "n"}
    assert "combined: within 1σ  within 2σ" in out
    for p in results["parameters"]:
        true = truth[str(p["region"])][p["parameter"]]
        assert p["true"] == (true if p["parameter"] == "n" else true[p["channel"]])
        assert abs(p["error_pct"]) < 2, p
        assert p["sys"] is not None  # the built-in rig has no calibration record: the stated shares
        assert p["z_combined"] <= p["z"]
    materials = [truth[k] for k in truth]
    assert all(8 <= m["n"] <= 500 and all(0.02 <= x <= 0.9 for x in m["rd"]) for m in materials)
    assert all(max(m["rd"]) + m["rs"][0] <= 1.0 + 1e-4 or m["rs"][0] == 0.05 for m in materials)
    code, out, err = run(capsys, "bench", "materials", "--objects", "teapot")
    assert code != 0
    assert "teapot" in err


@pytest.mark.slow
def test_fit_benchmark_prints_figures(capsys):
    code, out, err = run(capsys, "bench", "fit", "--no-grid", "--sizes", "200000")
    assert code == 0, err
    assert "M samples/s" in out
    assert "B/sample" in out


def test_the_command_list_says_what_each_command_says_of_itself():
    """`hlr-lab --help` lists commands from a table (so it imports none of them): the table must keep up."""
    from hlr_lab.cli.main import COMMANDS, cli

    ctx = click.Context(cli)
    for name, (_, summary) in COMMANDS.items():
        command = cli.get_command(ctx, name)
        assert command.name in (name, f"{name}_cmd", name.replace("_", "-"))
        assert command.get_short_help_str(limit=1000) == summary


def test_help_and_a_typo_load_nothing_heavy():
    """The numerical stack is loaded by the commands that use it, not to print help or a usage error."""
    script = (
        "import sys\n"
        "from hlr_lab.cli.main import main\n"
        "assert main(['--help']) == 0\n"
        "assert main(['acquir']) == 2\n"
        "heavy = sorted({'numpy', 'scipy', 'trimesh', 'pymodbus', 'dynamixel_sdk', 'cv2'} & set(sys.modules))\n"
        "assert not heavy, heavy\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "No such command 'acquir'" in done.stderr


@pytest.mark.parametrize(
    ("command", "said"),
    [
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--delta-e", "nan"],
            "'--delta-e': 'nan' is not a finite number",
        ),
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--min-samples", "inf"],
            "'--min-samples': 'inf' is not a finite",
        ),
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--sphere-scale", "nan"],
            "'--sphere-scale': 'nan' is not",
        ),
        (["plan", "--mesh", "builtin:pebble", "--sim", "--scale", "-inf"], "'--scale'"),
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--views", "nan"],
            "--views: nan is not a turntable angle",
        ),
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--views", "0,1e400"],
            "--views: inf is not a turntable angle",
        ),
        (
            ["plan", "--mesh", "builtin:pebble", "--sim", "--views", "720"],
            "--views: 720 is not a turntable angle",
        ),
        (
            ["segment", "--mesh", "builtin:pebble", "--delta-e", "nan"],
            "'--delta-e': 'nan' is not a finite number",
        ),
        (["acquire", "--plan", "p.json", "--sim", "--speed-factor", "nan"], "'--speed-factor': 'nan' is not"),
        (["acquire", "--plan", "p.json", "--sim", "--warm-up", "inf"], "'--warm-up': 'inf' is not a finite"),
    ],
)
def test_numbers_that_are_not_finite_or_out_of_range_are_refused_where_they_enter(
    tmp_path, capsys, command, said
):
    """NaN passes every range check (each comparison with it is false): each number option refuses it,
    and ±inf, naming the option; nothing is written."""
    out = ["-o", str(tmp_path / "x.json")] if command[0] in ("plan", "segment") else []
    assert main([*command, *out]) in (1, 2)
    assert said in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()
