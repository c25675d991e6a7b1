"""A study's summary: one row per trial, the best trial, files written."""

import csv

import optuna

from robomorph.tuning.summary import summarize, trial_rows


def _study():
    study = optuna.create_study(study_name="s", direction="minimize", sampler=optuna.samplers.RandomSampler(seed=0))

    def objective(trial):
        trial.set_user_attr("run_dir", f"runs/t{trial.number}")
        x = trial.suggest_int("n_layer", 1, 4)
        if trial.number == 2:
            raise optuna.TrialPruned()
        return float(x)

    study.optimize(objective, n_trials=4)
    return study


def test_rows_summary_and_files(tmp_path):
    study = _study()
    rows = trial_rows(study)
    assert [r["state"] for r in rows] == ["COMPLETE", "COMPLETE", "PRUNED", "COMPLETE"]
    assert all(r["run_dir"] == f"runs/t{r['number']}" and "n_layer" in r for r in rows)
    text = summarize(study, str(tmp_path))
    best = study.best_trial
    assert "trials: complete 3, pruned 1" in text
    assert f"**best**: trial {best.number}, value {best.value:.4g}" in text
    with open(tmp_path / "trials.csv", newline="") as f:
        assert [int(r["number"]) for r in csv.DictReader(f)] == [0, 1, 2, 3]
    assert (tmp_path / "summary.md").read_text() == text


def test_an_empty_study_says_so():
    text = summarize(optuna.create_study(study_name="empty"))
    assert "no complete trial yet" in text and "needs at least 2 complete trials (0 so far)" in text
