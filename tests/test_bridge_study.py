"""The study app takes a round recorded in the cell as a ROS 2 bag (from the study folder's
bags/), and learns the person's own durations and paths from it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from study_helpers import make_study

from rapidds.bridge.bag import write_bag
from rapidds.bridge.export import human_task_messages
from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.motion.policy import DiffusionPolicy
from rapidds.web.study.runner import InputError, StudySession, step_token
from rapidds.worlds.fetch.world import FetchWorld

S = 1_000_000_000


def test_a_bag_round_is_learned_as_the_bag_says(tmp_path: Path, fetch_world: FetchWorld,
                                                fetch_policy: DiffusionPolicy) -> None:
    folder = make_study(tmp_path, fetch_world)
    session = StudySession(folder, policy=fetch_policy, world=fetch_world)
    try:
        pid = session.store.participants()[0].id
        plan, _ = session.plan(pid)  # type: ignore[misc]
        tasks = plan.best.schedule.tasks("human")
        done = session.teammate(pid).execute(0, tasks, np.random.default_rng(7))
        msgs, at = [], 3 * S
        for t in tasks:  # the person's tasks one after the other, as the cell recorded them
            msgs += human_task_messages(fetch_world, t, done[t].trajectory, done[t].duration, at)
            at += round((done[t].duration + 1.0) * S)
        (folder / "bags").mkdir()
        write_bag(folder / "bags" / "round0.mcap", msgs)
        token = step_token(session.store.next_step(pid))
        for name in ("", "../round0.mcap", "missing.mcap"):  # refused, nothing stored
            with pytest.raises(InputError):
                session.submit_round(pid, token, "bag", {"bag": name})
        rec = session.submit_round(pid, token, "bag", {"bag": "round0.mcap"})
    finally:
        session.close()
    assert rec.observed == pytest.approx({t: done[t].duration for t in tasks}, abs=1e-8)
    with StudyStore.open_readonly(study_path(folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        assert len(s.records(rid)) == 1
        arrays = s.arrays(rid, 0)
    for t in tasks:
        np.testing.assert_allclose(arrays[f"human/{t}"], done[t].trajectory.reshape(
            arrays[f"human/{t}"].shape), atol=1e-8)
