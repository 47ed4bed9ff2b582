"""Unattended campaigns on the simulated rig: three jobs with a fault injected in the second (retried and
done; or skipped and the night goes on; or the rig left unconfirmed and everything stops), the
notification hook, the status, the index, and the campaign files and nights that are refused."""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path

import pytest

from hlr_lab.campaign import runner as c
from hlr_lab.campaign.runner import AcquireJob, CampaignStopped, campaign_status, load_campaign, run_campaign
from hlr_lab.errors import DiskFull, InputError
from tests.renderer_guard import require_renderer

require_renderer(module_level=True)


def campaign_file(
    tmp_path: Path, plan: Path, jobs: int = 3, extra: str = "", rig: Path | None = None
) -> Path:
    """A night of ``jobs`` runs of ``plan`` on the simulated rig (``rig``: on that rig file, the world too)."""
    text = f'[campaign]\nname = "test night"\n{extra}\n'
    on = "" if rig is None else f'rig = "{rig}"\n'
    for i in range(jobs):
        text += (
            f'\n[[job]]\nname = "j{i}"\nplan = "{plan}"\n{on}out = "s{i}"\nsim = true\nspeed_factor = 40\n'
        )
    path = tmp_path / "night.toml"
    path.write_text(text)
    return path


def links_with(fault: dict[str, callable]):
    """``links_for`` as the command line's (a simulated world per job), with ``fault[job name](world)``
    applied to that job's world."""

    def links_for(job: AcquireJob, stack: contextlib.ExitStack):
        from hlr_lab.formats.plan import read_plan
        from hlr_lab.instrument.devices import Links
        from sim.rig import SimRig
        from worlds.plan_world import sim_links, sim_scene, world_geometry

        rig = c.job_rig(job)
        if job.name not in fault:
            return sim_links(
                stack, rig, read_plan(job.plan), job.plan, job.scene, job.true_rig, job.speed_factor
            )
        world = stack.enter_context(SimRig(scene=sim_scene(read_plan(job.plan), job.plan, None),
                                           speed_factor=job.speed_factor, **world_geometry(rig)))  # fmt: skip
        fault[job.name](world)
        e = world.endpoints
        return Links(e.dynamixel, e.modbus, e.camera)

    return links_for


def no_calibration(job):
    raise AssertionError("no calibrate job here")


@pytest.mark.slow
def test_a_fault_in_the_second_job_is_retried_and_the_night_goes_on(tmp_path, builtin_plan, quarter_rig):
    """The second job's turntable answers one request with a device failure: that run stops safely, the
    job runs again on a new connection and completes (attempts 2, a job_retry line); all three are
    fitted and reported; the hook heard every job's end and the campaign's; status and index say so."""
    heard = tmp_path / "heard.jsonl"
    hook = f"notify = \"sh -c 'cat; echo' >> {heard}\""
    path = campaign_file(tmp_path, builtin_plan, extra=hook, rig=quarter_rig)
    night = load_campaign(path)

    def one_failure(world):
        world.turntable.faults.exception += 1

    results = run_campaign(night, links_for=links_with({"j1": one_failure}), calibrate=no_calibration)
    assert [(r.name, r.status, r.attempts) for r in results] == [("j0", "done", 1), ("j1", "done", 2),
                                                                 ("j2", "done", 1)]  # fmt: skip
    for r in results:
        assert Path(r.report).is_file()
        assert len(r.materials) == 4
    events = [json.loads(line) for line in (night.folder / "campaign.jsonl").read_text().splitlines()]
    assert [e["event"] for e in events].count("job_retry") == 1
    assert events[-1]["event"] == "campaign_end"
    summaries = [json.loads(line) for line in heard.read_text().splitlines() if line.strip()]
    assert [s["event"] for s in summaries] == ["job_end", "job_end", "job_end", "campaign_end"]
    assert summaries[1]["attempts"] == 2
    index = (night.folder / "index.html").read_text()
    assert index.count("report</a>") == 3
    status = list(campaign_status(night))
    assert status[1].startswith("j1: done")
    assert status[-1] == "campaign ended"


@pytest.mark.slow
def test_a_job_that_keeps_failing_is_skipped_and_a_rig_not_confirmed_safe_stops_everything(
    tmp_path, builtin_plan, quarter_rig
):
    """The second job's camera loses a packet of every frame for good: the run stops safely (lamp, turntable and gantry
    confirmed), is run once more, stops again, and is skipped; the third job still runs. Then a night
    whose second job's turntable refuses every request, the stop included: the rig is not confirmed
    safe, the campaign stops (exit status 1) and the third job never starts."""
    night = load_campaign(campaign_file(tmp_path, builtin_plan, rig=quarter_rig))

    def camera_broken(world):
        world.gige.faults.drop_for_good = 10**6

    results = run_campaign(night, links_for=links_with({"j1": camera_broken}), calibrate=no_calibration)
    assert [(r.name, r.status, r.attempts) for r in results] == [("j0", "done", 1), ("j1", "skipped", 2),
                                                                 ("j2", "done", 1)]  # fmt: skip
    assert "the rig is safe" in results[1].detail
    events = [
        json.loads(line)["event"] for line in (night.folder / "campaign.jsonl").read_text().splitlines()
    ]
    assert events.count("job_retry") == events.count("job_skip") == 1

    other = tmp_path / "other"
    other.mkdir()
    night = load_campaign(campaign_file(other, builtin_plan, rig=quarter_rig))

    def turntable_broken(world):
        world.turntable.faults.exception = 10**6

    with pytest.raises(CampaignStopped, match="NOT SAFE") as stopped:
        run_campaign(night, links_for=links_with({"j1": turntable_broken}), calibrate=no_calibration)
    assert stopped.value.exit_status == 1
    events = [json.loads(line) for line in (night.folder / "campaign.jsonl").read_text().splitlines()]
    assert [e.get("job") for e in events if e["event"] == "job_start"] == ["j0", "j1"]  # j2 never started
    assert events[-1]["event"] == "campaign_stopped"


def test_campaign_files_that_are_wrong_are_refused_with_the_field(tmp_path, builtin_plan):
    path = campaign_file(tmp_path, builtin_plan, jobs=1)
    (tmp_path / "thesis").mkdir()
    (tmp_path / "thesis" / "thesis.tex").write_text("mine")
    text = path.read_text()
    calibrating = text + '\n[[job]]\nkind = "calibrate"\nname = "c"\nprocedure = "radiometric"\nsim = true\n'
    for change, field in (
        (text + "colour = 3\n", "job[0].colour"),
        (text.replace(str(builtin_plan), str(tmp_path / "gone.json")), "job[0].plan"),
        (text.replace("sim = true\n", ""), "job[0].rig"),
        (text + '\n[[job]]\nname = "j0"\nplan = "x"\nout = "y"\nsim = true\n', "job[1].name"),
        (text.replace("sim = true\n", 'true_rig = "builtin:bench-night"\nrig = "r.toml"\n'), "job[0]"),
        (text + '\n[[job]]\nkind = "dance"\nname = "x"\n', "job[1]"),
        (
            text + f'\n[[job]]\nname = "j1"\nplan = "{builtin_plan}"\nout = "s0"\nsim = true\n',
            "job[1].out: job 'j1' would write into the session of job 'j0'",
        ),
        (text.replace('name = "j0"', 'name = "../j0"'), "job[0].name: '../j0': a job's name is"),
        (  # the same folder, written otherwise (issue 20, §3)
            text + f'\n[[job]]\nname = "j1"\nplan = "{builtin_plan}"\nout = "x/../s0"\nsim = true\n',
            "job[1].out: job 'j1' would write into the session of job 'j0'",
        ),
        (
            text
            + f'\n[[job]]\nname = "j1"\nplan = "{builtin_plan}"\nout = "{tmp_path / "s0"}"\nsim = true\n',
            "job[1].out: job 'j1' would write into the session of job 'j0'",
        ),
        (calibrating + 'output = "night.toml"\n', "job[1].output: "),  # over the campaign file itself
        (calibrating + f'output = "{builtin_plan}"\n', "is also this command's input"),  # over a job's plan
        (calibrating + 'output = "s0/rig.toml"\n', "lies in the session of an acquire job"),
        (text + 'warm_up_min = "30"\n', "job[0].warm_up_min: Input should be a valid number"),
        (  # a session is started in a new or empty folder, never among someone's files
            text.replace('out = "s0"', 'out = "thesis"'),
            "holds other files (thesis.tex): a session is started in a new or empty folder; give a new out for the job",
        ),
    ):
        path.write_text(change)
        (tmp_path / "r.toml").write_text("")
        with pytest.raises(InputError) as err:
            load_campaign(path)
        assert field in str(err.value), (field, str(err.value))


def test_a_night_that_will_not_fit_on_the_disk_is_refused_before_anything_moves(
    tmp_path, builtin_plan, monkeypatch
):
    night = load_campaign(campaign_file(tmp_path, builtin_plan))
    monkeypatch.setattr(c, "free_bytes", lambda _path: 100_000_000)  # 100 MB: three jobs need ~280 MB
    with pytest.raises(DiskFull, match="where jobs 'j0', 'j1', 'j2' write"):
        run_campaign(night, links_for=lambda *_: pytest.fail("no job may start"), calibrate=no_calibration)
    assert not (night.folder / "campaign.jsonl").exists()


def test_a_notify_hook_that_fails_or_hangs_does_not_stop_the_night(monkeypatch, caplog):
    monkeypatch.setattr(c, "NOTIFY_TIMEOUT_S", 0.5)
    c._notify("sleep 5", {"event": "job_end"})
    c._notify("exit 3", {"event": "job_end"})
    messages = [r.getMessage() for r in caplog.records]
    assert any("did not finish within 0.5 s" in m for m in messages)
    assert any("exited 3" in m for m in messages)


@pytest.mark.slow
def test_campaign_run_and_status_from_the_command_line_with_a_calibration_job(
    tmp_path, builtin_plan, quarter_rig, capsys
):
    """`hlr-lab campaign run`: a radiometric calibration, then a run on the rig file it writes (which
    does not exist when the night starts); `status` afterwards."""
    from hlr_lab.cli.main import main
    from hlr_lab.rig.file import load_rig

    path = tmp_path / "night.toml"
    path.write_text(f"""
[[job]]
kind = "calibrate"
name = "radiometry"
procedure = "radiometric"
rig = "{quarter_rig}"
sim = true
speed_factor = 40
output = "rig-radiometric.toml"

[[job]]
name = "pebble"
plan = "{builtin_plan}"
rig = "rig-radiometric.toml"
out = "s"
sim = true
speed_factor = 40
""")
    bad = tmp_path / "bad.toml"
    bad.write_text(path.read_text().replace('rig = "rig-radiometric.toml"', 'rig = "rig-elsewhere.toml"'))
    assert main(["campaign", "run", str(bad)]) == 1  # not a file, and no calibration of the night writes it
    assert "job[1].rig: job 'pebble': no such file" in capsys.readouterr().err
    assert main(["campaign", "run", str(path)]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().err
    assert re.search(r"radiometry\s*│\s*done", printed)
    assert re.search(r"pebble\s*│\s*done", printed)
    assert load_rig(tmp_path / "rig-radiometric.toml").file.calibration.radiometric is not None
    assert main(["campaign", "status", str(path)]) == 0
    assert "campaign ended" in capsys.readouterr().err


def test_status_of_a_night_whose_log_lies_says_so(tmp_path, builtin_plan):
    """A campaign.jsonl whose forecast is a string, and a job_end without its status (a hand-edited or
    damaged log): status reads what it can and says what it cannot, instead of an internal error."""
    import json

    night = load_campaign(campaign_file(tmp_path, builtin_plan, jobs=2))
    night.folder.mkdir()
    lines = [{"event": "campaign_start", "at": 0, "jobs": ["j0", "j1"], "forecast_s": {"j0": "ten", "j1": 60},
              "forecast_bytes": {}}, {"event": "job_start", "at": 1, "job": "j0"}, {"event": "job_end", "at": 2,
              "job": "j0"}]  # fmt: skip
    (night.folder / "campaign.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    status = list(campaign_status(night))
    assert status[0] == "j0: (no status) ()"
    assert status[1] == "j1: waiting"
    assert status[2].endswith("the forecast of its campaign_start line is damaged; time left unknown")


def test_a_night_with_a_failed_job_says_so_in_its_exit_status(tmp_path, capsys):
    """A calibrate job on a rig file without a board fails before anything moves; the night goes on to
    its end, prints the failed job in its table, and exits 1 naming it (a cron job or a notification
    script reads the exit status, not the table)."""
    from importlib import resources

    from hlr_lab.cli.main import main

    text = (resources.files("hlr_lab.data") / "sim-rig.toml").read_text(encoding="utf-8")
    start = text.index("[calibration.board]")
    end = text.index("[calibration.mirror_ball]")
    (tmp_path / "no-board.toml").write_text(text[:start] + text[end:])
    night = tmp_path / "night.toml"
    night.write_text("""
[campaign]
name = "night"

[[job]]
kind = "calibrate"
name = "camera"
procedure = "camera"
rig = "no-board.toml"
sim = true
output = "rig-camera.toml"
""")
    assert main(["campaign", "run", str(night)]) == 1
    err = capsys.readouterr().err
    assert re.search(r"camera\s*│\s*failed", err)
    assert "1 of 1 jobs did not complete: camera (failed)" in err
    assert not (tmp_path / "rig-camera.toml").exists()
    assert not (tmp_path / "calibration").exists()  # no empty photographs folder left behind


def test_an_acquire_job_left_to_the_lamp_defaults_journals_how_and_why(tmp_path, builtin_plan):
    """A rig whose radiometric record saw its lamp 3 % below warm when first lit: the job left to the
    defaults has its lamp warmed up and watched, and the campaign's journal says so and why (the job then
    fails on its world, before anything moves); the same job given --warm-up 0 --lamp-every 0 has no such
    line."""
    from tests.films import DRAWING

    rig = tmp_path / "rig.toml"
    rig.write_text(DRAWING.read_text() + '\n[calibration.radiometric]\ndate = "2026-12-07"\nhlr_lab = "0.1.0"\n'
                   "lamp_warm_up_change = 0.02\nlamp_short_of_warm = 0.01\n")  # fmt: skip

    def no_world(job, stack):
        raise InputError("no world here", path=job.plan)

    for extra, lines in (("", 1), ("warm_up_min = 0\nlamp_every = 0\n", 0)):
        folder = tmp_path / f"night-{lines}"
        folder.mkdir()
        path = campaign_file(folder, builtin_plan, jobs=1, rig=rig)
        path.write_text(path.read_text() + extra)
        results = run_campaign(load_campaign(path), links_for=no_world, calibrate=no_calibration)
        assert [r.status for r in results] == ["failed"]
        journal = [
            json.loads(line)
            for line in (folder / "night-campaign" / "campaign.jsonl").read_text().splitlines()
        ]
        lamp = [e for e in journal if e["event"] == "job_lamp"]
        assert len(lamp) == lines
        if lines:
            assert lamp[0]["job"] == "j0"
            assert lamp[0]["lamp"].startswith(
                "the lamp is warmed up (at most 30 min) and watched every 5 poses"
            )
            assert "3.0 % below warm when first lit" in lamp[0]["lamp"]
