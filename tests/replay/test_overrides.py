"""``--set FIELD=VALUE`` of the benchmarks (replay.harness.overrides) on the real settings classes."""

import pytest

from companion.gravity.sequential import SeqGravConfig
from companion.nav.navigator import NavigatorConfig
from replay.harness.overrides import apply_overrides


def test_fields_nested_fields_and_types():
    cfg = apply_overrides(SeqGravConfig(), ["resample_frac=0.25", "map_error.white_sigma_mgal=1", "n_particles=2000",
                                            "roughen=0.1"])
    assert cfg.resample_frac == 0.25 and cfg.n_particles == 2000 and isinstance(cfg.n_particles, int)
    assert cfg.map_error.white_sigma_mgal == 1.0 and cfg.map_error.corr_length_m == SeqGravConfig().map_error.corr_length_m
    assert cfg.roughen == 0.1
    nav = apply_overrides(NavigatorConfig(), ["motion_prior=false", "motion.min_age_s=2.5"])
    assert nav.motion_prior is False and nav.motion.min_age_s == 2.5


def test_an_optional_number_left_at_none_takes_a_number_or_none():
    base = SeqGravConfig(roughen=None)
    assert apply_overrides(base, ["roughen=0.2"]).roughen == 0.2
    assert apply_overrides(base, ["roughen=None"]).roughen is None


@pytest.mark.parametrize("item", ["no_such_field=1", "resample_frac", "map_error.no_such=1"])
def test_unknown_or_malformed_names_exit_with_the_known_fields(item):
    with pytest.raises(SystemExit, match="expected FIELD=VALUE"):
        apply_overrides(SeqGravConfig(), [item])


def test_a_value_of_the_wrong_type_exits_saying_so():
    with pytest.raises(SystemExit, match="'many' is not a int"):
        apply_overrides(SeqGravConfig(), ["n_particles=many"])
