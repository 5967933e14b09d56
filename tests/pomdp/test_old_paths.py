"""The old module paths of the models (before issue 32 gathered them in torchhrc.pomdp) still
hand out the very objects of their new modules, and every name the old modules exported, each
with a DeprecationWarning naming its new place (deprecated aliases for one release)."""

from __future__ import annotations

import importlib

import pytest

# old module -> the new modules its names now live in
MOVED = {
    "torchhrc.sparse": ("torchhrc.pomdp.sparse",),
    "torchhrc.sparse_momdp": ("torchhrc.pomdp.sparse_momdp",),
    "torchhrc.belief": ("torchhrc.pomdp.belief",),
    "torchhrc.observation": ("torchhrc.pomdp.observation", "torchhrc.pomdp.observation_fit"),
    "torchhrc.approach_observation": ("torchhrc.pomdp.approach_observation",),
}

# the __all__ of each old module before the move (a name dropped from a shim fails here)
OLD_ALL = {
    "torchhrc.sparse": {"MAX_DENSE_ENTRIES", "SparsePOMDP", "check_dense_size", "coalesce"},
    "torchhrc.sparse_momdp": {"SparseMOMDP"},
    "torchhrc.belief": {
        "BeliefUpdate", "correct", "log_matmul_exp", "log_update", "log_update_all",
        "momdp_correct", "momdp_log_update", "momdp_log_update_all", "momdp_predict",
        "momdp_predict_all", "momdp_update", "momdp_update_all", "predict", "predict_all",
        "update", "update_all",
    },
    "torchhrc.observation": {
        "DiscretizedGaussianObservation", "HandTracks", "ObservationFit", "ObservationGrid",
        "bivariate_normal_cdf", "discretize_positions", "discretized_gaussian",
        "fit_observation_model", "log_discretized_gaussian", "sample_positions",
        "simulate_tracks", "track_log_likelihood",
    },
    "torchhrc.approach_observation": {
        "ApproachFit", "ApproachObservation", "approach_log_likelihood", "fit_approach_observation",
    },
}  # fmt: skip


@pytest.mark.parametrize("old", sorted(MOVED))
def test_old_module_hands_out_the_new_objects(old):
    module = importlib.import_module(old)
    # a deprecated path has no __all__ (no API page); its table serves every old name
    assert not hasattr(module, "__all__")
    assert {n for n in module._MOVED if not n.startswith("_")} == OLD_ALL[old]
    new = [importlib.import_module(n) for n in MOVED[old]]
    for name in OLD_ALL[old]:
        owners = [m for m in new if name in m.__all__]
        assert len(owners) == 1, f"{old}.{name} is defined in {len(owners)} new modules"
        with pytest.warns(DeprecationWarning, match=f"use {owners[0].__name__}.{name}"):
            alias = getattr(module, name)
        assert alias is getattr(owners[0], name), f"{old}.{name}"
    with pytest.raises(AttributeError, match="no attribute"):
        module.not_a_name  # noqa: B018


def test_old_pomdp_names_are_the_package_names():
    import torchhrc
    import torchhrc.pomdp as package
    from torchhrc.pomdp import base, dense

    # the __all__ of the module torchhrc.pomdp before it became the package
    for name in ("MOMDP", "POMDP"):
        assert getattr(package, name) is getattr(dense, name)
    for name in ("check_initial", "initial_joint", "split_initial", "start_from"):
        assert getattr(package, name) is getattr(base, name)
    assert torchhrc.POMDP is dense.POMDP and torchhrc.MOMDP is dense.MOMDP
    assert torchhrc.SparsePOMDP is package.SparsePOMDP


def test_private_helpers_other_modules_import_still_resolve():
    from torchhrc.pomdp import observation_fit

    with pytest.warns(DeprecationWarning):
        from torchhrc.observation import _safe_log, _unpack_transition

    assert _safe_log is observation_fit._safe_log
    assert _unpack_transition is observation_fit._unpack_transition
