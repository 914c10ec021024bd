"""``rapidds gamma``: the belief over a person's gamma from comfort answers given by hand.

For cycles run with a person outside the browser (an experimenter asking, a questionnaire): each
``--answer A@PEAK`` is one cycle's comfort answer (1-7, agreement with "the robot came too close
to me") with the closeness the robot's nearest approach had that cycle (exp(-beta * distance),
the ``comfort.peak`` of a learning run's record); ``--signals N@EXPOSURE`` adds a cycle's count
of "too close" signals with its exposure. Prints the posterior after each piece of evidence
(``--json``: one object per step, ``given`` the evidence, ``evidence`` how many so far).
"""

from __future__ import annotations

import json
from typing import Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._options import run_settings


def _pair(text: str, what: str) -> tuple[float, float]:
    parts = text.split("@")
    try:
        if len(parts) != 2:
            raise ValueError
        return float(parts[0]), float(parts[1])
    except ValueError:
        fail(f"{what}, got {text!r}")
        raise AssertionError from None  # fail() exits


@app.command("gamma")
@run_settings("world", aliases={"--world": "world"})
def gamma_cmd(
    settings: dict[str, Any],
    answer: list[str] = typer.Option([], help="A cycle's comfort answer 1-7 with its peak "
                                      "closeness in [0, 1]: A@PEAK (repeat per cycle)."),
    signals: list[str] = typer.Option([], help="A cycle's 'too close' signals with its "
                                       "exposure (s at closeness 1): N@EXPOSURE."),
    prior: str | None = typer.Option(None, help="Prior G or G:SPREAD.",
                                     show_default="the world's gamma, spread 4"),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per step."),
) -> None:
    """Update a belief over a person's gamma with comfort answers and 'too close' signals."""
    from rapidds.human.gamma import DEFAULT_SPREAD, GammaBelief, GammaEvidence, parse_gamma_prior
    from rapidds.worlds.registry import make_world

    g_ref = make_world(settings["world"]).problem().objective.gamma
    try:
        g0, spread = parse_gamma_prior(prior) if prior is not None else (g_ref, DEFAULT_SPREAD)
    except ValueError as exc:
        fail(f"--prior: {exc}, got {prior!r}")
    steps: list[GammaEvidence] = []
    for text in answer:
        a, peak = _pair(text, "an answer is A@PEAK, e.g. 5@0.6")
        if not 0 <= peak <= 1:
            fail(f"--answer: the closeness PEAK is in [0, 1], got {text!r}")
        if a not in range(1, 8):
            fail(f"--answer: a comfort answer is an integer 1-7, got {text!r}")
        steps.append(GammaEvidence(int(a), (), (), peak, 0.0))
    for text in signals:
        n, exposure = _pair(text, "signals are N@EXPOSURE, e.g. 2@1.5")
        if n < 0 or n != int(n) or not exposure >= 0:
            fail(f"--signals: N is a count and EXPOSURE >= 0, got {text!r}")
        steps.append(GammaEvidence(None, tuple(0.0 for _ in range(int(n))),
                                   tuple(1.0 for _ in range(int(n))), 1.0, exposure))
    belief = GammaBelief(g0, spread, g_ref)
    rows = [{"step": 0, "given": None, **belief.summary()}]
    for k, ev in enumerate(steps, 1):
        belief.observe(ev)
        rows.append({"step": k, "given": ev.to_dict(), **belief.summary()})
    for row in rows:
        if as_json:
            typer.echo(json.dumps(row))
        else:
            typer.echo(f"{row['step']:>3}  gamma {row['mean']:.3g}  (80 % in {row['q10']:.3g}"
                       f"-{row['q90']:.3g})")
