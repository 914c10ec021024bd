"""``rapidds plan``: JSON and text output, reproducibility, the exact solver, bad options."""

from __future__ import annotations

import filecmp
import json
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.core import TyperGroup
from typer.testing import CliRunner, Result

from rapidds.bundled import example_names, example_path, resolve_problem
from rapidds.cli import _register, app
from rapidds.cli.plan import sample_durations
from rapidds.errors import ProblemError
from rapidds.motion.interface import FixedDurationMotion
from rapidds.problem import Problem, load_problem
from rapidds.render import (
    makespan_line,
    makespan_stats,
    render_gantt,
    render_sequences,
    wait_intervals,
)
from rapidds.schedule import Schedule, Wait, compile_schedule, validate

ROOT = Path(__file__).resolve().parents[1]
FETCH = ROOT / "tests" / "data" / "four-fetch.yaml"
FAST = ["--population", "16", "--generations", "15", "--samples", "48"]
FIELDS = {
    "human", "robot", "expected_makespan", "objective", "feasible", "makespan_std", "spatial",
    "diversity", "seed", "solver", "seconds", "samples", "sampling",
}


def invoke(*args: str) -> Result:
    """Run ``rapidds plan ARGS``. Typer collapses an app with one command into that command,
    so while ``plan`` is the only one registered the word 'plan' is dropped from argv."""
    _register()
    single = not isinstance(typer.main.get_command(app), TyperGroup)
    return CliRunner().invoke(app, list(args) if single else ["plan", *args])


def plan_json(*args: str) -> dict:
    result = invoke(*args, "--json")
    assert result.exit_code == 0, result.output
    assert result.stderr == ""  # no progress bar when stderr is not a terminal
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1  # ONE JSON object
    return json.loads(lines[0])


def recompute(problem: Problem, report: dict) -> np.ndarray:
    """Makespan per Monte-Carlo sample of the reported schedule, from scratch."""
    schedule = Schedule.from_json(report)
    compiled = compile_schedule(problem, schedule)
    assert compiled is not None
    samples, _ = sample_durations(problem, report["seed"], report["samples"], report["sampling"])
    robot = FixedDurationMotion(problem).nominal_durations(problem)
    return compiled.simulate(compiled.durations(samples, robot)).makespan


@pytest.fixture(scope="module")
def fetch() -> Problem:
    return load_problem(FETCH)


@pytest.fixture(scope="module")
def ga_report() -> dict:
    return plan_json(str(FETCH), "--seed", "7", *FAST)


@pytest.fixture(scope="module")
def exact_report() -> dict:
    return plan_json(str(FETCH), "--seed", "7", "--samples", "48", "--exact")


def test_json_fields_and_feasible_schedule(fetch, ga_report):
    assert set(ga_report) >= FIELDS
    assert ga_report["solver"] == "ga"
    assert ga_report["feasible"] is True
    assert ga_report["seed"] == 7 and ga_report["samples"] == 48
    assert ga_report["generations_run"] >= 1
    assert all(isinstance(x, str) for x in ga_report["human"] + ga_report["robot"])
    schedule = Schedule.from_json(ga_report)
    validate(fetch, schedule)  # every task exactly once, on an allowed agent
    assert compile_schedule(fetch, schedule) is not None  # no deadlock


def test_makespan_matches_a_recomputed_timeline(fetch, ga_report):
    makespan = recompute(fetch, ga_report)
    assert ga_report["expected_makespan"] == pytest.approx(makespan.mean(), rel=1e-12)
    assert ga_report["makespan_std"] == pytest.approx(makespan.std(), rel=1e-9)
    assert ga_report["makespan_p5"] == pytest.approx(np.percentile(makespan, 5))
    # no geometry: spatial 0; lambda 0: the objective is the expected makespan
    assert ga_report["spatial"] == 0.0
    assert ga_report["objective"] == pytest.approx(
        ga_report["expected_makespan"] + ga_report["gamma"] * ga_report["spatial"]
        + ga_report["lambda"] * ga_report["diversity"]
    )
    # the makespan of a fixed schedule is convex in the durations: E[makespan] >= at the mean
    _, mean = sample_durations(fetch, 7, 1)
    compiled = compile_schedule(fetch, Schedule.from_json(ga_report))
    assert compiled is not None
    robot = FixedDurationMotion(fetch).nominal_durations(fetch)
    at_mean = compiled.simulate(compiled.durations(mean.reshape(1, -1), robot)).makespan[0]
    assert ga_report["expected_makespan"] >= at_mean - 1e-9


def test_same_seed_same_json(ga_report):
    again = plan_json(str(FETCH), "--seed", "7", *FAST)
    first = {k: v for k, v in ga_report.items() if k != "seconds"}
    assert {k: v for k, v in again.items() if k != "seconds"} == first
    other = plan_json(str(FETCH), "--seed", "8", *FAST)
    assert other["expected_makespan"] != ga_report["expected_makespan"]  # other samples


def test_seed_defaults_to_a_reported_random_one(fetch):
    report = plan_json(str(FETCH), *FAST)
    assert isinstance(report["seed"], int) and report["seed"] >= 0
    assert report["expected_makespan"] == pytest.approx(recompute(fetch, report).mean())


def test_bundled_name_equals_file():
    by_name = plan_json("fetch", "--seed", "7", *FAST)
    by_file = plan_json(str(ROOT / "examples" / "fetch.yaml"), "--seed", "7", *FAST)
    assert by_name["human"] == by_file["human"] and by_name["robot"] == by_file["robot"]
    assert by_name["expected_makespan"] == by_file["expected_makespan"]


def test_exact_json(fetch, exact_report, ga_report):
    r = exact_report
    assert set(r) >= FIELDS
    assert r["solver"] == "cp-sat"
    assert r["optimal"] is True and r["status"] == "OPTIMAL"
    assert r["feasible"] is True
    validate(fetch, Schedule.from_json(r))
    # fetch on mean durations: one bottom object each (max(8, 9) = 9), then the robot's 13 s top
    assert r["makespan_at_mean"] == pytest.approx(22.0)
    assert r["expected_makespan"] == pytest.approx(recompute(fetch, r).mean(), rel=1e-12)
    assert r["expected_makespan"] >= r["makespan_at_mean"] - 1e-9
    # same seed and samples: the GA optimises exactly this quantity, so it is never worse
    assert ga_report["expected_makespan"] <= r["expected_makespan"] + 1e-9


def test_weights_and_sampling_options(fetch):
    r = plan_json(str(FETCH), "--seed", "3", *FAST, "--gamma", "0.5", "--lam", "2",
                  "--sampling", "plugin")
    assert (r["gamma"], r["lambda"], r["sampling"]) == (0.5, 2.0, "plugin")
    assert r["objective"] == pytest.approx(r["expected_makespan"] + 2.0 * r["diversity"])
    assert r["expected_makespan"] == pytest.approx(recompute(fetch, r).mean(), rel=1e-12)


@pytest.mark.parametrize("name", ["painting", "painting-constrained", "random-8"])
def test_other_examples_plan_feasibly(name):
    problem = load_problem(example_path(name))
    r = plan_json(name, "--seed", "1", *FAST)
    assert r["feasible"] is True
    schedule = Schedule.from_json(r)
    validate(problem, schedule)
    for task in schedule.tasks("human"):
        assert problem.task(task).can("human")
    compiled = compile_schedule(problem, schedule)
    assert compiled is not None
    samples, _ = sample_durations(problem, 1, 8)
    robot = FixedDurationMotion(problem).nominal_durations(problem)
    tl = compiled.simulate(compiled.durations(samples, robot))
    idx = problem.index
    for a, b in problem.precedence:
        assert np.all(tl.finish[:, idx[a]] <= tl.start[:, idx[b]] + 1e-9)


def test_text_output():
    result = invoke(str(FETCH), "--seed", "7", *FAST)
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "fetch: genetic search, seed 7" in out
    assert "expected makespan" in out and "p5–p95" in out
    assert "objective" in out
    gantt = [line for line in out.splitlines() if line.startswith(("human [", "robot ["))]
    assert len(gantt) == 2  # one Gantt row per agent
    assert "\x1b[" not in out  # no colour codes when piped
    exact = invoke("fetch", "--exact")
    assert exact.exit_code == 0, exact.output
    assert "exact CP-SAT" in exact.stdout and "optimal" in exact.stdout


def test_unknown_problem_name_lists_bundled():
    result = invoke("no-such-example")
    assert result.exit_code == 2
    assert "no such file or bundled example" in result.stderr
    assert "fetch" in result.stderr


def test_bundled_examples_match_the_repository_copies():
    repo = sorted(p.stem for p in (ROOT / "examples").glob("*.yaml"))
    assert repo == example_names()
    for name in example_names():
        assert filecmp.cmp(ROOT / "examples" / f"{name}.yaml", example_path(name), shallow=False)
    assert example_path("fetch.yaml") == example_path("fetch")
    with pytest.raises(ProblemError, match="no bundled example"):
        example_path("../fetch")
    repo_fetch = ROOT / "examples" / "fetch.yaml"
    assert resolve_problem(repo_fetch) == repo_fetch  # an existing file wins over a bundled name


# --- text rendering ---------------------------------------------------------------------------


def _timeline(problem: Problem, schedule: Schedule, human: list[float]):
    compiled = compile_schedule(problem, schedule)
    assert compiled is not None
    robot = FixedDurationMotion(problem).nominal_durations(problem)
    return compiled.simulate(compiled.durations(np.array([human]), robot))


def test_gantt_shows_tasks_and_waits(fetch):
    # human: t3 (8) t2 (8) t1 (12); robot waits for t2 (until 16), then t0 (13): makespan 29
    s = Schedule(("t3", "t2", "t1"), (Wait("t2"), "t0"))
    tl = _timeline(fetch, s, [12.0, 12.0, 8.0, 8.0])
    assert tl.makespan[0] == pytest.approx(29.0)
    assert wait_intervals(tl, "robot") == [(Wait("t2"), 0.0, 16.0)]
    text = render_gantt(tl, width=58)  # 2 characters per second
    rows = {line.split(" ", 1)[0]: line for line in text.splitlines()}
    human, robot = rows["human"][6:], rows["robot"][6:]
    assert human == "[t3" + "-" * 12 + "][t2" + "-" * 12 + "][t1" + "-" * 20 + "]"
    assert robot == "~" * 32 + "[t0" + "-" * 22 + "]"
    assert len(robot) == 58
    listing = render_sequences(tl)
    assert "wait for t2" in listing and "idle 16.0 s" in listing


def test_gantt_wait_without_delay_and_tiny_tasks(fetch):
    s = Schedule(("t2", "t0"), ("t3", Wait("t2"), "t1"))
    tl = _timeline(fetch, s, [12.0, 12.0, 8.0, 8.0])
    assert wait_intervals(tl, "robot") == [(Wait("t2"), 9.0, 9.0)]  # t2 done at 8: no idle
    text = render_gantt(tl, width=10)
    assert "~" not in text.splitlines()[2]
    assert "no delay" in render_sequences(tl)


def test_makespan_line_format():
    assert makespan_line([10.0, 10.0, 10.0]) == (
        "expected makespan 10.0 s (sd 0.0, p5–p95 10.0–10.0)"
    )
    m = np.linspace(20.0, 30.0, 101)
    stats = makespan_stats(m)
    assert stats["mean"] == pytest.approx(25.0)
    assert (stats["p5"], stats["p95"]) == pytest.approx((20.5, 29.5))
    assert makespan_line(m) == (
        f"expected makespan 25.0 s (sd {m.std():.1f}, p5–p95 20.5–29.5)"
    )
    with pytest.raises(ValueError):
        makespan_line([])
