"""``rapidds plan PROBLEM``: one plan for a problem file, by genetic search or exact CP-SAT.

Human durations come from the problem file's priors (a new teammate, no cycles observed yet);
robot durations from the file (:class:`FixedDurationMotion`, no geometry, so the spatial term is
0). Both solvers are reported on the same Monte-Carlo duration samples, so ``--exact`` and the
genetic plan can be compared number for number.
"""

from __future__ import annotations

import json
import math
import secrets
import shutil
import time
from typing import TYPE_CHECKING, Any, cast

import typer

from rapidds.cli import app, fail
from rapidds.cli._options import AS_JSON, describe
from rapidds.cli._progress import progress
from rapidds.errors import RapiddsError
from rapidds.scheduler.config import GAConfig
from rapidds.settings import require_memory

if TYPE_CHECKING:
    import numpy as np

    from rapidds.human.temporal import Sampling
    from rapidds.motion.interface import FixedDurationMotion
    from rapidds.problem import Problem
    from rapidds.schedule import Timeline
    from rapidds.scheduler import Evaluation

_GA = GAConfig()  # the defaults shown in --help are the scheduler's own


def sample_durations(
    problem: Problem, seed: int, samples: int, sampling: Sampling = "predictive"
) -> tuple[np.ndarray, np.ndarray]:
    """The (K, n) human duration samples and (n,) means ``plan`` scores schedules on.

    The samples use their own stream spawned from ``seed`` (the search uses ``seed`` itself), so
    the two never share random numbers; public so a test or a script can reproduce the numbers.
    """
    import numpy as np

    from rapidds.human.temporal import TemporalModel

    temporal = TemporalModel.from_problem(problem, sampling=sampling)
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    return temporal.sample(samples, rng), temporal.mean()


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _check_options(
    population: int, generations: int, samples: int, seed: int | None,
    gamma: float | None, lam: float | None, sampling: str, time_limit: float,
) -> None:
    """Reject bad option values with one line before any work starts."""
    if population < 2:
        fail(f"--population must be >= 2, got {population}")
    for name, value in (("--generations", generations), ("--samples", samples)):
        if value < 1:
            fail(f"{name} must be >= 1, got {value}")
    if seed is not None and seed < 0:
        fail(f"--seed must be >= 0, got {seed}")
    for name, w in (("--gamma", gamma), ("--lam", lam)):
        if w is not None and not (math.isfinite(w) and w >= 0):
            fail(f"{name} must be a finite number >= 0, got {w}")
    from rapidds.human.temporal import SAMPLING_METHODS  # numpy: not at import (--help)

    if sampling not in SAMPLING_METHODS:
        fail(f"--sampling must be one of {', '.join(SAMPLING_METHODS)}, got {sampling!r}")
    if not (math.isfinite(time_limit) and time_limit > 0):
        fail(f"--time-limit must be a number of seconds > 0, got {time_limit}")


def _expected_timeline(
    problem: Problem, evaluation: Evaluation, human_mean: np.ndarray
) -> Timeline:
    """The plan at mean human durations and the chosen robot motions' durations (K = 1)."""
    from rapidds.motion.interface import FixedDurationMotion
    from rapidds.schedule import compile_schedule

    compiled = compile_schedule(problem, evaluation.schedule)
    assert compiled is not None  # only called for feasible plans
    robot = FixedDurationMotion(problem).nominal_durations(problem)
    for task, motion in evaluation.motions.items():
        robot[problem.index[task]] = motion.duration
    return compiled.simulate(compiled.durations(human_mean.reshape(1, -1), robot))


def _report(problem: Problem, evaluation: Evaluation, extra: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    mk = np.asarray(evaluation.makespan, dtype=float)
    sched = evaluation.schedule.to_json()
    out: dict[str, Any] = {
        "problem": problem.name,
        "human": sched["human"],
        "robot": sched["robot"],
        "feasible": bool(evaluation.feasible),
        "objective": _finite_or_none(evaluation.objective),
        "expected_makespan": _finite_or_none(evaluation.makespan_mean),
        "makespan_std": _finite_or_none(evaluation.makespan_std),
        "makespan_p5": float(np.percentile(mk, 5)) if mk.size else None,
        "makespan_p95": float(np.percentile(mk, 95)) if mk.size else None,
        "spatial": _finite_or_none(evaluation.spatial),
        "diversity": _finite_or_none(evaluation.diversity),
        "gamma": problem.objective.gamma,
        "lambda": problem.objective.lam,
        "converged": bool(evaluation.converged),
    }
    out.update(extra)
    return out


def _print_text(
    problem: Problem, evaluation: Evaluation, report: dict[str, Any], human_mean: np.ndarray
) -> None:
    from rapidds.render import key_value_table, makespan_line, render_gantt, render_sequences

    width = max(40, min(100, shutil.get_terminal_size((88, 24)).columns - 8))
    if report["solver"] == "cp-sat":
        head = (f"{problem.name}: exact CP-SAT on mean durations "
                f"({'optimal' if report['optimal'] else report['status'].lower()}, "
                f"{report['seconds']:.2f} s)")
    else:
        head = (f"{problem.name}: genetic search, seed {report['seed']} "
                f"({report['generations_run']} generations, {report['evaluations']} evaluations, "
                f"{report['seconds']:.2f} s)")
    typer.echo(head)
    if not evaluation.feasible:
        typer.echo("no feasible schedule found (every candidate deadlocks)")
        return
    timeline = _expected_timeline(problem, evaluation, human_mean)
    typer.echo("")
    typer.echo(render_sequences(timeline, width=width + 8))
    typer.echo("")
    typer.echo(render_gantt(
        timeline, width=width,
        title=f"at mean durations (makespan {float(timeline.makespan[0]):.1f} s):",
    ))
    typer.echo("")
    typer.echo(f"{makespan_line(evaluation.makespan)} over {report['samples']} "
               f"{report['sampling']} samples")
    g, lam = problem.objective.gamma, problem.objective.lam
    typer.echo(key_value_table([
        ("objective", f"{evaluation.objective:.2f}"),
        ("  makespan", f"{evaluation.makespan_mean:.2f}"),
        ("  + gamma x spatial", f"{g:g} x {evaluation.spatial:.3f}"),
        ("  + lambda x diversity", f"{lam:g} x {evaluation.diversity:.3f}"),
    ], width=width + 8))
    if not evaluation.converged:
        typer.echo("note: the overlap loop did not converge; best evaluated variant shown")


@app.command("plan")
def plan(
    problem: str = typer.Argument(
        ..., help="Problem YAML file, or the name of a bundled example (fetch, painting, ...)."
    ),
    seed: int | None = typer.Option(
        None, min=0, max=2**63 - 1, help="Random seed for duration samples and the search.",
        show_default="random, reported",
    ),
    population: int = typer.Option(_GA.population, min=2, max=100_000,
                                   help=describe("population")),
    generations: int = typer.Option(_GA.generations, min=1, max=1_000_000,
                                    help=describe("generations")),
    samples: int = typer.Option(_GA.samples, min=1, max=100_000, help=describe("samples")),
    gamma: float | None = typer.Option(
        None, help="Proximity weight.", show_default="the problem file's"
    ),
    lam: float | None = typer.Option(
        None, help="Diversity weight lambda.", show_default="the problem file's"
    ),
    sampling: str = typer.Option(
        "predictive", help="Human duration samples: predictive (Student-t) or plugin (Normal)."
    ),
    exact: bool = typer.Option(
        False, "--exact", help="Solve with OR-Tools CP-SAT on mean durations instead of the GA."
    ),
    time_limit: float = typer.Option(10.0, help="CP-SAT time limit in seconds (with --exact)."),
    as_json: bool = AS_JSON,
) -> None:
    """Plan one cycle for a new teammate: who does what, in which order, where to wait."""
    _check_options(population, generations, samples, seed, gamma, lam, sampling, time_limit)
    from rapidds.motion.interface import FixedDurationMotion

    prob = _load(problem, gamma, lam, population, samples)
    if seed is None:
        seed = secrets.randbelow(2**31)
    human_samples, human_mean = sample_durations(prob, seed, samples, cast("Sampling", sampling))
    motion = FixedDurationMotion(prob)
    common = {"seed": seed, "samples": samples, "sampling": sampling}
    if exact:
        evaluation, extra = _solve_exact(prob, motion, time_limit, human_samples, human_mean)
    else:
        config = _ga_config(population, generations, samples, seed)
        evaluation, extra = _solve_ga(prob, motion, config, human_samples, human_mean,
                                      quiet=as_json)
    report = _report(prob, evaluation, {**extra, **common})
    if as_json:
        typer.echo(json.dumps(report, allow_nan=False))
    else:
        _print_text(prob, evaluation, report, human_mean)
    if not evaluation.feasible:
        raise typer.Exit(1)


def _load(problem: str, gamma: float | None, lam: float | None, population: int,
          samples: int) -> Problem:
    """The problem file (or bundled example) with the objective's weights set; refused with one
    line when it is bad or its search would not fit in memory."""
    from rapidds.bundled import resolve_problem
    from rapidds.problem import load_problem

    try:
        prob = load_problem(resolve_problem(problem)).with_objective(gamma, lam)
        # a generation's Monte-Carlo timelines: C candidates x K samples x n tasks, a few arrays
        require_memory(8 * 8 * population * samples * len(prob.tasks),
                       "this search (--population x --samples)")
    except RapiddsError as exc:
        fail(str(exc))
        raise  # not reached: fail exits
    return prob


def _ga_config(population: int, generations: int, samples: int, seed: int) -> GAConfig:
    try:
        return GAConfig(population=population, generations=generations, samples=samples,
                        seed=seed)
    except ValueError as exc:
        fail(str(exc))
        raise  # not reached: fail exits


def _solve_exact(prob: Problem, motion: FixedDurationMotion, time_limit: float,
                 human_samples: np.ndarray, human_mean: np.ndarray,
                 ) -> tuple[Evaluation, dict[str, Any]]:
    """CP-SAT on mean durations, then scored on the same samples as the genetic search."""
    from rapidds.motion.interface import TrajectoryCache
    from rapidds.scheduler import EvaluationContext, evaluate_population
    from rapidds.scheduler.exact import solve_exact

    t0 = time.perf_counter()
    try:
        result = solve_exact(prob, time_limit_s=time_limit)
    except RapiddsError as exc:
        fail(str(exc))
        raise  # not reached: fail exits
    seconds = time.perf_counter() - t0
    evaluation = evaluate_population(EvaluationContext(
        prob, human_samples, human_mean, TrajectoryCache(motion),
        motion.nominal_durations(prob), prob.objective.gamma, prob.objective.lam,
    ), [result.schedule])[0]
    return evaluation, {
        "solver": "cp-sat", "optimal": bool(result.optimal), "status": str(result.status),
        "makespan_at_mean": float(result.makespan), "bound": float(result.bound),
        "seconds": seconds,
    }


def _solve_ga(prob: Problem, motion: FixedDurationMotion, config: GAConfig,
              human_samples: np.ndarray, human_mean: np.ndarray, *, quiet: bool,
              ) -> tuple[Evaluation, dict[str, Any]]:
    """The genetic search, with a progress bar unless ``quiet``."""
    from rapidds.scheduler import GeneticScheduler

    with progress("generations", config.generations, quiet=quiet) as update:
        result = GeneticScheduler(prob, motion, config).solve(
            human_samples, human_mean,
            progress=lambda g, best: update(g, f"best {best:.2f}" if math.isfinite(best)
                                            else ""),
        )
    return result.best, {
        "solver": "ga", "generations_run": int(result.generations_run),
        "evaluations": int(result.evaluations), "seconds": float(result.seconds),
        "population": config.population,
    }
