"""Gravity-aided navigation: maps, Eotvos, the gravity-gradient tensor, the matchers (one module per paper under
:mod:`companion.gravity.matchers`), the particle filters (Liu 2019), fix fusion and the product's match stage
(:mod:`companion.gravity.stage`). Pure numerics: no I/O but map loading, no asyncio, no wall clock."""

from companion.gravity.data import shared_gravity_dir
from companion.gravity.eotvos import correct_eotvos_mgal, eotvos_from_ne_mgal, eotvos_mgal
from companion.gravity.maps import (GravityMap, LocalGravityMap, MapFormatError, MapStats, bilinear, load_grid,
                                    map_statistics, tasman_land_mask)
from companion.gravity.matchers import (IccpMatcher, KnnMatcher, MatchFailure, Matcher, MatchResult, MatchWindow,
                                        MsdSequenceMatcher, PatternConfig, RegularMetricMap, RpcmMatcher,
                                        SequenceSearchConfig, SpeedConstraint, TercomMatcher,
                                        equivalence_range_from_noise)

__all__ = [
    "GravityMap", "LocalGravityMap", "MapFormatError", "MapStats", "bilinear", "load_grid", "map_statistics",
    "tasman_land_mask", "shared_gravity_dir", "eotvos_mgal", "eotvos_from_ne_mgal", "correct_eotvos_mgal",
    "Matcher", "MatchWindow", "MatchResult", "MatchFailure", "SpeedConstraint", "SequenceSearchConfig",
    "KnnMatcher", "MsdSequenceMatcher", "IccpMatcher", "equivalence_range_from_noise", "PatternConfig",
    "RegularMetricMap", "RpcmMatcher", "TercomMatcher",
]
