"""One contract for every gravity matcher behind companion.gravity.matchers.base.Matcher (batch and online)."""

import numpy as np
import pytest

from companion.gravity import (IccpMatcher, KnnMatcher, MatchWindow, MsdSequenceMatcher, PatternConfig, RpcmMatcher,
                               TercomMatcher)
from companion.gravity.matchers import Matcher, ViterbiConfig, ViterbiMatcher
from tests.gravity.test_matchers import LMAP, _window
from tests.helpers import subclasses


def _all_matchers(lmap):
    pc = dict(cell_m=500.0, min_len=10, window_len=60)
    return [
        KnnMatcher(lmap),
        MsdSequenceMatcher(lmap),
        IccpMatcher(lmap, equivalence_mgal=(-0.3, 0.3)),
        RpcmMatcher(lmap, PatternConfig(metric="msd", **pc)),
        RpcmMatcher(lmap, PatternConfig(metric="mad", **pc)),
        TercomMatcher(lmap, PatternConfig(metric="msd", **pc)),
        TercomMatcher(lmap, PatternConfig(metric="mad", **pc)),
        # the product's variant (companion.gravity.stage.make_matcher: RVBMP-2i, o 5, T 6), on half the map's cells
        ViterbiMatcher(lmap, ViterbiConfig(o=5, T=6, sigma_z_mgal=0.3, subcell_values="interp"), cell_m=250.0),
    ]


def test_every_matcher_of_the_package_is_under_contract():
    """A new Matcher subclass in companion.gravity.matchers must join the list above."""
    product = {c for c in subclasses(Matcher) if c.__module__.startswith("companion.") and not c.__name__.startswith("_")}
    assert product == {type(m) for m in _all_matchers(LMAP)}


@pytest.mark.parametrize("matcher", _all_matchers(LMAP), ids=lambda m: m.name)
def test_interface_contract(matcher):
    win, true = _window(LMAP, (300.0, -300.0), n=30, spacing_m=700.0)
    # batch: a good window gives a finite fix with uncertainty and timing
    r = matcher.match(win)
    assert r.ok, r.reason
    assert r.position_ne_m.shape == (2,) and np.all(np.isfinite(r.position_ne_m))
    assert np.isfinite(r.sigma_m) and r.sigma_m > 0 and r.compute_time_s > 0
    assert r.t_s == win.t_s[-1] and r.method == matcher.name
    assert r.track_ne_m is None or r.track_ne_m.shape[1] == 2
    # bad input: failed result with a reason, never an exception
    empty = MatchWindow.of([], np.zeros((0, 2)), np.zeros((0, 2)), [])
    for bad, why in [
        (empty, "empty"),
        (MatchWindow.of(win.t_s, win.ins_ne_m, win.ins_vel_ne_mps, np.where(np.arange(len(win)) == 3, np.nan, win.gravity_mgal)), "non-finite"),
        (MatchWindow.of(win.t_s[:3], win.ins_ne_m[:3], win.ins_vel_ne_mps[:3], win.gravity_mgal[:3]), "need"),
        (MatchWindow.of(win.t_s, win.ins_ne_m + 1e6, win.ins_vel_ne_mps, win.gravity_mgal), ""),
    ]:
        rb = matcher.match(bad)
        assert not rb.ok and why in rb.reason and rb.reason and np.all(np.isnan(rb.position_ne_m))
    # online: nothing until min_len samples, then a fix every fix_every samples, each equal to the batch match of
    # the samples it was fed (before the speed constraint of continuous matching, if the matcher has one)
    matcher.reset()
    outs = [matcher.feed(win.t_s[i], win.ins_ne_m[i], win.ins_vel_ne_mps[i], win.gravity_mgal[i]) for i in range(len(win))]
    assert all(o is None for o in outs[: matcher.min_len - 1])
    due = [i for i in range(matcher.min_len - 1, len(win)) if (i - matcher.min_len + 1) % matcher.fix_every == 0]
    assert [i for i, o in enumerate(outs) if o is not None] == due
    for i in due:
        assert outs[i].ok, outs[i].reason
        lo = max(0, i + 1 - matcher.window_len)
        batch = matcher.match(MatchWindow(win.t_s[lo:i + 1], win.ins_ne_m[lo:i + 1], win.ins_vel_ne_mps[lo:i + 1],
                                          win.gravity_mgal[lo:i + 1]))
        raw = outs[i].extra.get("raw_position_ne_m", outs[i].position_ne_m)
        np.testing.assert_array_equal(raw, batch.position_ne_m)
        assert outs[i].sigma_m == batch.sigma_m and outs[i].method == batch.method
    assert np.linalg.norm(outs[due[-1]].position_ne_m - true[due[-1]]) < 1000.0
    # online bad samples are dropped with a reason and do not poison later fixes
    bad = matcher.feed(win.t_s[-1] + 10.0, win.ins_ne_m[-1], win.ins_vel_ne_mps[-1], float("nan"))
    assert bad is not None and not bad.ok and "non-finite" in bad.reason
    late = matcher.feed(win.t_s[-1], win.ins_ne_m[-1], win.ins_vel_ne_mps[-1], win.gravity_mgal[-1])
    assert late is not None and not late.ok and "time" in late.reason
    nxt = None
    for k in range(1, matcher.fix_every + 1):
        nxt = matcher.feed(win.t_s[-1] + 140.0 * k, win.ins_ne_m[-1] + [0.0, 700.0 * k], win.ins_vel_ne_mps[-1],
                           float(LMAP.interp_ne(true[-1, 0], true[-1, 1] + 700.0 * k)))
    assert nxt is not None and nxt.ok


@pytest.mark.parametrize("matcher", _all_matchers(LMAP), ids=lambda m: m.name)
def test_prior_is_an_argument_not_a_mutation(matcher):
    """The caller's prior changes one match (for matchers that take one) and leaves the matcher as it was."""
    win, _ = _window(LMAP, (300.0, -300.0), n=30, spacing_m=700.0)
    name, cfg = matcher.name, getattr(matcher, "cfg", None)
    with_prior = matcher.match(win, prior_sigma_m=250.0)
    assert with_prior.ok and with_prior.method == matcher.method_name(250.0)
    assert matcher.name == name and getattr(matcher, "cfg", None) == cfg
    if not matcher.supports_prior:
        np.testing.assert_array_equal(with_prior.position_ne_m, matcher.match(win).position_ne_m)
