"""The study storage: SQLite files open, unreachable storages are named."""

import optuna
import pytest

from robomorph.tuning.space import SpaceError
from robomorph.tuning.storage import open_storage


def test_a_sqlite_storage_keeps_studies(tmp_path):
    url = f"sqlite:///{tmp_path}/s.db"
    study = optuna.create_study(study_name="a", storage=open_storage(url))
    study.optimize(lambda t: t.suggest_float("x", 0, 1), n_trials=2)
    again = optuna.load_study(study_name="a", storage=open_storage(url))
    assert len(again.trials) == 2


def test_an_unreachable_storage_names_the_url(tmp_path):
    url = f"sqlite:///{tmp_path}/no/such/folder/s.db"
    with pytest.raises(SpaceError, match="cannot open the study storage .*no/such/folder"):
        open_storage(url)
