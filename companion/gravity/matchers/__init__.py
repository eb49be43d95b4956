"""Gravity matchers behind one `Matcher` base (batch `match(window)`, online `feed(...)`), one module per paper:

* :mod:`.gao_knn`: KNN and MSD sequence matching (Gao et al. 2022)
* :mod:`.gao_iccp`: ICCP (Gao et al. 2022)
* :mod:`.wu_pattern`: RPCM and TERCOM (Wu et al. 2015)
* :mod:`.li_viterbi`: Viterbi map matching VBMP / RVBMP / RVBMP-2 (Li et al. 2022)

(Liu et al. 2019's particle filters track a state rather than match a window: :mod:`companion.gravity.particle`.)
"""

from companion.gravity.matchers.base import MatchFailure, Matcher, MatchResult, MatchWindow, SpeedConstraint
from companion.gravity.matchers.gao_iccp import IccpMatcher, equivalence_range_from_noise
from companion.gravity.matchers.gao_knn import KnnMatcher, MsdSequenceMatcher, SequenceSearchConfig
from companion.gravity.matchers.li_viterbi import CellMap, ViterbiConfig, ViterbiMatcher
from companion.gravity.matchers.wu_pattern import PatternConfig, RegularMetricMap, RpcmMatcher, TercomMatcher

__all__ = [
    "Matcher", "MatchWindow", "MatchResult", "MatchFailure", "SpeedConstraint", "SequenceSearchConfig",
    "KnnMatcher", "MsdSequenceMatcher", "IccpMatcher", "equivalence_range_from_noise", "PatternConfig",
    "RegularMetricMap", "RpcmMatcher", "TercomMatcher", "CellMap", "ViterbiConfig", "ViterbiMatcher",
]
