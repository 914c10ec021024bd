"""Every command answers bad input with one line on stderr and exit code 2, never a traceback.

This table is the reference of what each bad input gets (the file-system and store cases, which
need real files, are in ``test_cli_errors.py`` and ``test_store.py``). Each case runs through
``rapidds.cli.main`` in this process, exactly as the console script does.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import pytest

from rapidds.cli import main

DATA = Path(__file__).resolve().parent / "data"
HUGE = "name: h\ntasks:\n  - id: a\n    human: {mean: 1e308, std: 1.0}\n    robot: {duration: 4}\n"
CYCLIC = ("name: c\ntasks:\n  - {id: a, allowed: [human], human: {mean: 1.0}}\n"
          "  - {id: b, allowed: [human], human: {mean: 1.0}}\n"
          "precedence: [[a, b], [b, a]]\n")

CASES: list[tuple[str, str]] = [
    # plan
    ("plan fetch --samples 100000000", "Invalid value for '--samples'"),
    ("plan fetch --population 1", "Invalid value for '--population'"),
    ("plan fetch --population 0", "Invalid value for '--population'"),
    ("plan fetch --samples 0", "Invalid value for '--samples'"),
    ("plan fetch --gamma nan", "--gamma must be a finite number >= 0"),
    ("plan fetch --exact --time-limit 0", "--time-limit must be a number of seconds > 0"),
    ("plan fetch --population 100000 --samples 100000", "would need about"),
    ("plan fetch --seed -3", "Invalid value for '--seed'"),
    ("plan fetch --generations 0", "Invalid value for '--generations'"),
    ("plan fetch --gamma inf", "--gamma must be a finite number >= 0"),
    ("plan fetch --lam -1", "--lam must be a finite number >= 0"),
    ("plan fetch --time-limit nan", "--time-limit must be a number of seconds > 0"),
    ("plan fetch --sampling magic", "--sampling must be one of predictive, plugin"),
    ("plan nowhere.yaml", "nowhere.yaml: no such file or bundled example"),
    ("plan {huge}", "mean must be at most 1e+07 s, got 1e+308"),
    ("plan {cyclic}", "cycle"),
    ("plan fetch --bogus", "No such option: --bogus"),
    # run
    ("run --samples 100000000", "--samples: Input should be less than or equal to 100000"),
    ("run --population 100000 --samples 100000", "would need about"),
    ("run --particles 4096 --candidates 4096", "would need about"),
    ("run --seed -1", "--seed: Input should be greater than or equal to 0"),
    ("run --gamma inf", "--gamma: Input should be a finite number"),
    ("run --gamma -1", "--gamma: Input should be greater than or equal to 0"),
    ("run --lam nan", "--lam: Input should be a finite number"),
    ("run --cycles 0", "--cycles: Input should be greater than or equal to 1"),
    ("run --human nobody", "unknown human 'nobody' for world fetch; one of fast-middle"),
    ("run --variant upside-down", "world 'fetch' has no variant 'upside-down'"),
    ("run moon", "unknown world 'moon'; available: fetch"),
    ("run --adapt magic", "--adapt: Input should be 'full', 'spatial'"),
    ("run --threads 0", "Invalid value for '--threads'"),
    ("run --resume", "--resume needs --out"),
    ("run --policy {missing}", "does not exist"),
    # sample
    ("sample --world fetch --task t3 -n 100000000", "Invalid value for '-n'"),
    ("sample --world fetch --task t3 -n 0", "Invalid value for '-n'"),
    ("sample --world fetch --task t3 -n 1000000 --candidates 4096", "would need about"),
    ("sample --world fetch --task t9", "task 't9' is not one of the policy's tasks"),
    ("sample --world fetch --task t3 --seed -1", "Invalid value for '--seed'"),
    ("sample --world fetch --task t3 --concurrent t7", "no spatial model for human task(s)"),
    ("sample --world fetch --task t3 --gamma inf", "--gamma must be a finite number >= 0"),
    ("sample --world fetch --task t3 --candidates 0", "Invalid value for '--candidates'"),
    ("sample --world moon --task t3", "unknown world 'moon'"),
    ("sample --task t3", "--policy is required without --world"),
    ("sample --task t3 --policy {missing}", "does not exist"),
    # train-policy
    ("train-policy --out {tmp}/p --world moon", "unknown world 'moon'"),
    ("train-policy --out {tmp}/p --world fetch --steps -1",
     "DiffusionConfig.steps: Input should be greater than or equal to 1"),
    ("train-policy --out {tmp}/p --world fetch --demos-per-mode 0", "--demos-per-mode must be"),
    ("train-policy --out {tmp}/p", "give --demos FILE, --world NAME, or --world NAME --demos"),
    ("train-policy --out {tmp}/p --world fetch --demos {missing}", "no such bag or folder"),
    ("train-policy --out {tmp}/p --demos {missing}.npz", "does not exist"),
    # ablation and report
    ("ablation --out {tmp}/ab --trials 0", "--trials: Input should be greater than or equal to 1"),
    ("ablation --out {tmp}/ab --humans nobody", "--humans: unknown value 'nobody'"),
    ("ablation --out {tmp}/ab --adapt magic", "--adapt: unknown value 'magic'"),
    ("ablation --out {tmp}/ab --seed -1", "--seed: Input should be greater than or equal to 0"),
    ("ablation --out {tmp}/ab --workers 0", "--workers must be >= 1"),
    ("ablation --out {tmp}/ab --scheduler nonsense", "scheduler"),
    ("ablation --out {tmp}/ab --policy distilled", "fetch ships no policy of that name"),
    ("study simulate --out {tmp}/s --policy {tmp}", "missing config.json"),
    ("report {tmp}", "holds no study"),
    # painting and its case study
    ("run painting --variant upside-down", "world 'painting' has no variant 'upside-down'"),
    ("run painting --human nobody", "unknown human 'nobody' for world painting"),
    ("case-study painting --out {tmp}/cs --human nobody", "unknown teammate 'nobody'"),
    ("case-study painting --out {tmp}/cs --settings sideways-g3", "unknown painting setting"),
    ("case-study painting --out {tmp}/cs --settings ,", "--settings names no setting"),
    ("case-study fetch --out {tmp}/cs", "no case study for world 'fetch'"),
    ("case-study painting --out {tmp}/cs --cycles 0", "Invalid value for '--cycles'"),
    ("case-study painting", "Missing option '--out'"),
    ("case-study painting --out {tmp}/cs --policy nowhere", "painting ships no policy of that"),
    # study (the flag a user can type, bounds on a task's duration)
    ("study design --out {tmp}/s --participants 15", "--allow-unbalanced"),
    ("study design --out {tmp}/s --participants 16 --max-task-seconds 0",
     "max_task_s: Input should be greater than 0"),
    ("study design --out {tmp}/s --participants 16 --max-task-seconds 1e9",
     "max_task_s: Input should be less than or equal to 3600"),
    ("study serve {tmp}", "holds no study"),
    # the others
    ("demo --cycles 0", "--cycles: Input should be greater than or equal to 1"),
    ("demo moon", "unknown world 'moon'"),
    ("worlds --bogus", "No such option: --bogus"),
    ("nonsense", "No such command 'nonsense'"),
]


@pytest.mark.parametrize(("command", "answer"), CASES, ids=[c for c, _ in CASES])
def test_bad_input_gets_one_line_and_exit_2(command, answer, tmp_path, monkeypatch, capsys):
    (tmp_path / "huge.yaml").write_text(HUGE)
    (tmp_path / "cyclic.yaml").write_text(CYCLIC)
    argv = shlex.split(command.format(tmp=tmp_path, huge=tmp_path / "huge.yaml",
                                      cyclic=tmp_path / "cyclic.yaml",
                                      missing=tmp_path / "missing"))
    monkeypatch.setattr(sys, "argv", ["rapidds", *argv])
    monkeypatch.chdir(tmp_path)  # nothing may be written outside the test's folder
    with pytest.raises(SystemExit) as exit_:
        main()
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert exit_.value.code == 2, err
    assert len(lines) == 1 and lines[0].startswith("rapidds: error: "), err
    assert answer in lines[0], lines[0]
    assert "Traceback" not in err
