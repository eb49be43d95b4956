"""Gravity map matching: maps, matcher interface, KNN/MSD/ICCP (Gao 2022), RPCM/TERCOM (Wu 2015)."""

from companion.matching.base import MatchFailure, Matcher, MatchResult, MatchWindow, SpeedConstraint
from companion.matching.data import shared_gravity_dir
from companion.matching.eotvos import correct_eotvos_mgal, eotvos_from_ne_mgal, eotvos_mgal
from companion.matching.iccp import IccpMatcher, equivalence_range_from_noise
from companion.matching.knn import KnnMatcher, MsdSequenceMatcher, SequenceSearchConfig
from companion.matching.maps import (GravityMap, LocalGravityMap, MapFormatError, MapStats, bilinear, load_grid,
                                     map_statistics, tasman_land_mask)
from companion.matching.pattern import PatternConfig, RegularMetricMap, RpcmMatcher, TercomMatcher

__all__ = [
    "GravityMap", "LocalGravityMap", "MapFormatError", "MapStats", "bilinear", "load_grid", "map_statistics",
    "tasman_land_mask", "shared_gravity_dir", "eotvos_mgal", "eotvos_from_ne_mgal", "correct_eotvos_mgal",
    "Matcher", "MatchWindow", "MatchResult", "MatchFailure", "SpeedConstraint", "SequenceSearchConfig",
    "KnnMatcher", "MsdSequenceMatcher", "IccpMatcher", "equivalence_range_from_noise", "PatternConfig",
    "RegularMetricMap", "RpcmMatcher", "TercomMatcher",
]
