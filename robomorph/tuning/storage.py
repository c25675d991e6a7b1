"""Where studies live: the Optuna storage (SQLite by default, or any SQLAlchemy URL)."""

from __future__ import annotations

import os

import optuna

from robomorph.tuning.space import SpaceError

DEFAULT_DIR = "results/sweeps"


def open_storage(url: str | None, heartbeat: int = 60, grace: int = 180):
    """An RDB storage (SQLite default, or any SQLAlchemy URL) with heartbeats and retries.

    Raises:
        SpaceError: the storage cannot be reached (the URL and the driver's reason).
    """
    if url is None:
        os.makedirs(DEFAULT_DIR, exist_ok=True)
        url = f"sqlite:///{DEFAULT_DIR}/optuna.db"
    # SQLite: wait for the file lock instead of failing when workers write at once.
    engine = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {"pool_pre_ping": True}
    try:
        return optuna.storages.RDBStorage(
            url, engine_kwargs=engine, heartbeat_interval=heartbeat, grace_period=grace,
            heartbeat_stale_trial_callback=optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=2))
    except Exception as exc:  # noqa: BLE001  (SQLAlchemy/driver errors vary by backend)
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SpaceError(f"cannot open the study storage {url!r}: {reason}. Check the URL, that the "
                         "server is running and reachable, and the credentials") from exc
