"""What a model records of the data it trains on, and the check that data fits the model.

The record (channel names, sample time, window lengths, input formulation, training stores
and their content fingerprints) is saved in every checkpoint under
:data:`robomorph.inference.checkpoint.DATA_INFO_KEY`: evaluation checks a store against it, takes
its defaults from it and marks a copy of the training data as in-sample.
"""

from __future__ import annotations

from robomorph.core.errors import RoboMorphError
from robomorph.data.fingerprints import fingerprint, robot_hashes
from robomorph.data.store import open_store
from robomorph.inference.checkpoint import CheckpointError


def data_info(dm) -> dict:
    """Channel names, sample time and window lengths of a set-up DataModule (JSON-able), and
    a content fingerprint of each training store (evaluate and calibrate recognize a copy)."""
    return {"u_names": list(dm.u_names), "y_names": list(dm.y_names), "dt": float(dm.dt),
            "context_len": int(dm.context_len), "horizon": int(dm.horizon),
            "stores": [str(s) for s in dm.stores], "inputs": str(getattr(dm, "inputs", "total")),
            "store_fingerprints": {str(s): fingerprint(str(s)) for s in dm.stores},
            "robot_hashes": {str(s): robot_hashes(str(s)) for s in dm.stores},
            # The arms it learned: evaluate and control refuse another one's data.
            "arms": _arms(dm.stores),
            # Stores of several arms: each training layout, so a Predictor maps an arm's arrays.
            **({"channel_mask": True, "layouts": dm.layouts} if getattr(dm, "channel_mask", False) else {})}


def _arms(stores: list[str]) -> list[str]:
    """The arms (store ``domain``: panda, kinova3, ...) the training stores record, sorted."""
    domains = (open_store(str(s), allow_incomplete=True).attrs.get("domain") for s in stores)
    return sorted({str(d) for d in domains if d})


def check_channels(dm, n_u: int | None, n_y: int | None, channel_mask: bool = False) -> None:
    """Refuses to train or test a model on a DataModule whose channel counts differ from its own.

    Raises:
        RoboMorphError: the model was built without ``n_u`` / ``n_y``.
        CheckpointError: the data has other channel counts than the model.
    """
    if n_u is None or n_y is None:
        raise RoboMorphError("the model has no n_u/n_y: pass them (robomorph fit links them from the data)")
    if (dm.n_u, dm.n_y) != (n_u, n_y):
        raise CheckpointError(
            f"the data has n_u={dm.n_u}, n_y={dm.n_y} but the model was built for n_u={n_u}, n_y={n_y}"
        )
    if getattr(dm, "channel_mask", False) and not channel_mask:
        raise CheckpointError("the data's stores lack some of its channels (arms with fewer joints), but the model "
                              "was built without channel_mask: build it with channel_mask=True (robomorph fit links it)")
