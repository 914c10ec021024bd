import json
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np

from rapidds.plots.curves import plot_run_costs, plot_study_panels
from rapidds.plots.gantt import save_gantt
from rapidds.problem import Problem, Task
from rapidds.record import CycleRecord
from rapidds.schedule import Schedule, Wait, compile_schedule


def _drawn(path):
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 50 and img.shape[1] > 50
    return float(img[..., :3].std())


def test_gantt_png_has_content(tmp_path):
    both = frozenset({"human", "robot"})
    p = Problem("p", (Task("a", both, 3.0, 0.0, 2.0), Task("b", both, 4.0, 0.0, 5.0)))
    s = Schedule(("a",), (Wait("a"), "b"))
    tl = compile_schedule(p, s).simulate(np.array([[3.0, 5.0]]))
    out = save_gantt(tl, tmp_path / "g.png", title="cycle 0")
    assert _drawn(out) > 0.05


def test_cost_curves_and_study_panels(tmp_path):
    base = json.loads((Path(__file__).parent / "data" / "records-3412e09-fetch.json")
                      .read_text())[0]
    recs = [CycleRecord.from_json({
        **base, "cycle": c, "gamma": 1.0,
        "expected": {**base["expected"], "makespan": 10.0 - c, "spatial": 0.5},
        "realised": {**base["realised"], "cost": 11.0 - c, "makespan": 10.0 - c,
                     "spatial": 0.4}}) for c in range(4)]
    assert _drawn(plot_run_costs(recs, tmp_path / "c.png", exploration_end=2)) > 0.05
    rng = np.random.default_rng(0)
    curves = {"fast": {"full": rng.random((3, 5)), "none": rng.random((3, 5)) + 1}}
    for suffix in ("png", "pdf"):
        out = plot_study_panels(curves, tmp_path / f"s.{suffix}", exploration_end=2.5)
        assert out.stat().st_size > 1000
    assert _drawn(tmp_path / "s.png") > 0.05
