"""Where studies live: the Optuna storage (SQLite by default, or any SQLAlchemy URL)."""

from __future__ import annotations

import os

import optuna

from robomorph.tuning.space import SpaceError

DEFAULT_DIR = "results/sweeps"
DEFAULT_URL = f"sqlite:///{DEFAULT_DIR}/optuna.db"
# The PostgreSQL driver this package installs (pyproject: psycopg2-binary). SQLAlchemy 2.1
# maps a plain ``postgresql://`` URL to psycopg 3, which is not installed.
_PG_DRIVER = "psycopg2"


def normalize_url(url: str) -> str:
    """The SQLAlchemy URL to open: ``postgresql://`` and ``postgres://`` (no driver named)
    get the installed driver; URLs naming a driver, and other databases, are unchanged."""
    for scheme in ("postgresql://", "postgres://"):
        if url.startswith(scheme):
            return f"postgresql+{_PG_DRIVER}://" + url[len(scheme):]
    return url


def storage_identity(url: str | None) -> str:
    """A storage's name for records: the normalized URL, an SQLite file as an absolute path,
    no password."""
    from sqlalchemy.engine import make_url  # noqa: PLC0415

    url = normalize_url(url or DEFAULT_URL)
    if url.startswith("sqlite:///") and url != "sqlite:///:memory:":
        return "sqlite:///" + os.path.abspath(url[len("sqlite:///"):])
    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001  (a malformed URL is recorded as given)
        return url


def open_storage(url: str | None, heartbeat: int = 60, grace: int = 180):
    """An RDB storage (SQLite default, or any SQLAlchemy URL) with heartbeats and retries.

    Raises:
        SpaceError: the storage cannot be reached (the URL and the driver's reason).
    """
    if url is None:
        os.makedirs(DEFAULT_DIR, exist_ok=True)
        url = DEFAULT_URL
    url = normalize_url(url)
    # SQLite: wait for the file lock instead of failing when workers write at once.
    engine = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {"pool_pre_ping": True}
    try:
        return optuna.storages.RDBStorage(
            url, engine_kwargs=engine, heartbeat_interval=heartbeat, grace_period=grace,
            heartbeat_stale_trial_callback=optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=2))
    except Exception as exc:  # noqa: BLE001  (SQLAlchemy/driver errors vary by backend)
        raise SpaceError(_storage_problem(url, exc)) from exc


def _storage_problem(url: str, exc: BaseException) -> str:
    """One line: what failed opening ``url``, blaming the driver or the server as the case is."""
    from sqlalchemy.engine import make_url  # noqa: PLC0415

    try:
        shown = make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001  (a malformed URL is shown as given)
        shown = url
    cause = exc
    while cause is not None and not isinstance(cause, ImportError):
        cause = cause.__cause__ or cause.__context__
    if isinstance(cause, ImportError):
        return (f"cannot open the study storage {shown!r}: its database driver is not installed "
                f"({cause}); install it, or name an installed driver in the URL "
                "(e.g. postgresql+psycopg2://user@host/db)")
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return (f"cannot open the study storage {shown!r}: {reason}. Check the URL, that the server is "
            "running and reachable, and the credentials")
