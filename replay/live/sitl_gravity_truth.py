"""SITL's truth in place of one input of the companion's air-data reference, for offline re-runs of a kept flight
(replay.live.sitl_gravity_rerun ``--truth-heading``, ``--truth-wind``, ``--perfect-gravimeter``): which input limits
the companion's own error, measured by replacing it alone.

* heading: SIMSTATE yaw (interpolated, unwrapped) instead of the gyro heading, in the GNSS period too (the wind is
  then learnt along it);
* wind: instead of the wind held from the GNSS period, at every dead-reckoning step the true wind as the reference
  sees it: the truth's displacement over ``window_s`` centred on the step, divided by ``window_s``, minus the mean of
  the recorded true airspeed along SIMSTATE yaw over the same window (so the airspeed's scale error and the sideslip
  are in it; the gusts faster than the window are not, as in a held wind);
* gravimeter: every reading replaced by what a perfect one would give: the mean over its output window of the map at
  the true positions plus the Eotvos term of the truth's mean velocity over that window (no misfit, bias, drift,
  noise or time-stamp jitter).

Truth is ``replay.live.sitl_core.FlightLog.truth`` / ``truth_yaw`` (SIMSTATE at the harness's rate, boot seconds).
Pure: no files, no wall clock.
"""

from __future__ import annotations

import math

import numpy as np

from companion.gravity.air_data import AirDataReckoner, radii_m
from companion.gravity.eotvos import eotvos_from_ne_mgal


class TruthTrack:
    """SIMSTATE's position (local north/east metres about its first sample) and yaw, interpolated in time."""

    def __init__(self, truth: list[tuple[float, float, float]], truth_yaw: list[tuple[float, float]]) -> None:
        tr = np.asarray(truth, float)
        if tr.ndim != 2 or len(tr) < 2:
            raise ValueError("the truth needs at least two (t, lat, lon) samples")
        keep = np.concatenate([[True], np.diff(tr[:, 0]) > 0])
        tr = tr[keep]
        self.t_s, self.lat_deg, self.lon_deg = tr[:, 0], tr[:, 1], tr[:, 2]
        ty = np.asarray(truth_yaw, float).reshape(-1, 2)
        if len(ty):
            ty = ty[np.concatenate([[True], np.diff(ty[:, 0]) > 0])]
        self.yaw_t_s, self.yaw_unwrapped_rad = ty[:, 0], np.unwrap(ty[:, 1]) if len(ty) else ty[:, 1]

    def yaw_rad(self, t_s) -> np.ndarray | float:
        """SIMSTATE yaw at t_s (wrapped to [-pi, pi))."""
        if not len(self.yaw_t_s):
            raise ValueError("the kept log has no SIMSTATE yaw")
        y = np.interp(t_s, self.yaw_t_s, self.yaw_unwrapped_rad)
        return (y + math.pi) % (2.0 * math.pi) - math.pi

    def displacement_ne_m(self, t0_s, t1_s) -> np.ndarray:
        """North/east metres from the truth at t0_s to the truth at t1_s (the radii at their mid-latitude)."""
        la0, lo0 = self.lat_lon_deg(t0_s)
        la1, lo1 = self.lat_lon_deg(t1_s)
        mid = 0.5 * (la0 + la1)
        rm, rn = np.vectorize(radii_m)(mid)
        return np.stack([np.radians(la1 - la0) * rm, np.radians(lo1 - lo0) * rn * np.cos(np.radians(mid))], -1)

    def lat_lon_deg(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        return np.interp(t_s, self.t_s, self.lat_deg), np.interp(t_s, self.t_s, self.lon_deg)


class TruthWind:
    """The true wind as the reference sees it (module doc), on a ``step_s`` grid, linear in between.

    ``tas_t_s``, ``tas_mps``: the recorded true airspeed (the reference's: VFR_HUD's, EAS -> TAS)."""

    def __init__(self, track: TruthTrack, tas_t_s, tas_mps, window_s: float = 60.0, step_s: float = 1.0) -> None:
        if not (window_s > 0 and step_s > 0):
            raise ValueError("window_s and step_s must be > 0")
        ts, tas = np.asarray(tas_t_s, float), np.asarray(tas_mps, float)
        ok = np.isfinite(ts) & np.isfinite(tas)
        ts, tas = ts[ok], tas[ok]
        if len(ts) < 2:
            raise ValueError("the truth wind needs recorded airspeeds")
        t0, t1 = max(track.t_s[0], ts[0]), min(track.t_s[-1], ts[-1])
        fine = np.arange(t0, t1, 0.1)  # air velocity along the true yaw, integrated on a 0.1 s grid
        yaw = track.yaw_unwrapped_rad if len(track.yaw_t_s) else None
        if yaw is None:
            raise ValueError("the kept log has no SIMSTATE yaw")
        y = np.interp(fine, track.yaw_t_s, yaw)
        v = np.interp(fine, ts, tas)
        air_ne = np.stack([v * np.cos(y), v * np.sin(y)], 1)
        cum = np.zeros((len(fine), 2))
        cum[1:] = np.cumsum(0.5 * (air_ne[1:] + air_ne[:-1]) * 0.1, axis=0)
        h = 0.5 * window_s
        self.t_s = np.arange(t0 + h, t1 - h, step_s)
        a = np.stack([np.interp(self.t_s + h, fine, cum[:, k]) - np.interp(self.t_s - h, fine, cum[:, k])
                      for k in (0, 1)], 1)
        self.wind_ne_mps = (track.displacement_ne_m(self.t_s - h, self.t_s + h) - a) / window_s
        self.window_s = float(window_s)

    def at(self, t_s: float) -> np.ndarray:
        return np.array([np.interp(t_s, self.t_s, self.wind_ne_mps[:, k]) for k in (0, 1)])


class TruthReckoner(AirDataReckoner):
    """Air-data dead reckoning with SIMSTATE yaw as its heading (``yaw``) and/or the true wind in place of the held
    one (``wind``)."""

    def __init__(self, cfg=None, *, yaw: TruthTrack | None = None, wind: TruthWind | None = None) -> None:
        super().__init__(cfg)
        self._truth_yaw, self._truth_wind = yaw, wind

    def heading(self, t_s: float, yaw_rad: float) -> None:
        super().heading(t_s, float(self._truth_yaw.yaw_rad(t_s)) if self._truth_yaw is not None else yaw_rad)

    def advance(self, t_s: float) -> bool:
        if self._truth_wind is not None and self.t is not None and t_s > self.t and self._wind:
            self.wind_held = self._truth_wind.at(t_s)
        return super().advance(t_s)


def perfect_reading_mgal(track: TruthTrack, lmap, t_s: float, window_s: float = 30.0) -> float:
    """A perfect gravimeter's reading at t_s (module doc): map at the truth samples in (t_s - window_s, t_s], plus the
    Eotvos term of the mean velocity over that window. NaN off the map or without truth there."""
    i0, i1 = np.searchsorted(track.t_s, [t_s - window_s, t_s], side="right")
    if i1 <= i0 or t_s - window_s < track.t_s[0] or t_s > track.t_s[-1]:
        return math.nan
    n, e = lmap.xy_to_ne(track.lon_deg[i0:i1], track.lat_deg[i0:i1])
    g = float(np.mean(lmap.interp_ne(np.asarray(n), np.asarray(e))))
    v = track.displacement_ne_m(t_s - window_s, t_s) / window_s
    lat, _ = track.lat_lon_deg(t_s - 0.5 * window_s)
    return g + float(eotvos_from_ne_mgal(v, float(lat)))


class FilterTrace:
    """Per reading the air-data stage's filter takes on its own (not anchored), its estimates beside the truth's:
    the reference's position error (reference - truth, map north/east m), the held wind's error (m/s) and the
    heading's error (rad), each estimated (mean, 1 sigma) and true, and the filter's status. Installed on a stage
    (companion.gravity.air_data_stage.AirDataGravityStage) by wrapping its filter's ``feed``."""

    def __init__(self, stage, track: TruthTrack, wind: TruthWind) -> None:
        self.stage, self.track, self.wind = stage, track, wind
        self.rows: list[dict] = []
        feed = stage.filter.feed

        def traced(t_s, g_mgal, ref_pos_ne_m, ref_vel_ne_mps, sigma_mgal, **kw):
            e = feed(t_s, g_mgal, ref_pos_ne_m, ref_vel_ne_mps, sigma_mgal, **kw)
            if e is not None and not kw.get("anchor"):
                self._row(float(t_s), np.asarray(ref_pos_ne_m, float), e)
            return e

        stage.filter.feed = traced

    def _row(self, t_s: float, ref_ne_m: np.ndarray, e) -> None:
        st, tr = self.stage, self.track
        lat, lon = tr.lat_lon_deg(t_s)
        tn, te = st.lmap.xy_to_ne(np.array(lon), np.array(lat))
        ref_err = ref_ne_m - np.array([float(tn), float(te)])
        w = st.dr.wind_held
        wind_err = (np.asarray(w, float) - self.wind.at(t_s)) if w is not None else np.full(2, math.nan)
        vel = e.vel_err_ne_mps if e.vel_err_ne_mps is not None else np.full(2, math.nan)
        vsig = np.sqrt(np.diag(e.vel_cov_ne_m2ps2)) if e.vel_cov_ne_m2ps2 is not None else np.full(2, math.nan)
        y = st.dr._yaw
        head_err = math.nan if y is None else float((y[1] - tr.yaw_rad(y[0]) + math.pi) % (2 * math.pi) - math.pi)
        head_est = head_sig = math.nan
        be = st.filter.be
        if st.cfg.ins.air_heading and hasattr(be, "xl"):
            from companion.gravity.sequential_backends import IPSI

            k = IPSI + 2
            head_est = float(be.w @ be.xl[:, k])
            head_sig = math.sqrt(float(be.Pl[k, k]) + float(be.w @ (be.xl[:, k] - head_est) ** 2))
        self.rows.append({"t_s": t_s, "ref_err_ne_m": ref_err, "est_err_ne_m": np.asarray(e.err_ne_m, float).copy(),
                          "h_acc_m": float(e.h_acc_m),
                          "unaided_h_m": math.sqrt(float(np.trace(st.filter.unaided_cov_ne_m2()))), "wind_err_ne_mps": wind_err, "wind_est_ne_mps": np.asarray(vel),
                          "wind_sigma_ne_mps": vsig, "heading_err_rad": head_err, "heading_est_rad": head_est,
                          "heading_sigma_rad": head_sig, "status": e.status, "nis_mean": float(e.nis_mean),
                          "reinit_count": int(e.reinit_count), "bimodality": float(e.bimodality),
                          "signal_ratio": float(e.signal_ratio),
                          "nis": float(st.filter._nis[-1][1]) if st.filter._nis else math.nan})

    def lines(self, on_s: float, minutes) -> list[str]:
        """One line per minute mark after ``on_s``: the reading nearest to it (within 5 s), and the mean normalised
        innovation of the readings since the previous mark."""
        if not self.rows:
            return ["  (no readings on the filter's own)"]
        t = np.array([r["t_s"] for r in self.rows])
        out = ["  min | own err / h_acc / unaided h_acc (m) | ref err: true / est (m) | wind err N,E: true / est +- sigma (m/s) | "
               "heading err: true / est +- sigma (deg) | status | NIS"]
        nis = np.array([r.get("nis", math.nan) for r in self.rows])
        prev = on_s
        for m in minutes:
            since = (t > prev) & (t <= on_s + 60.0 * m)
            prev = on_s + 60.0 * m
            i = int(np.argmin(np.abs(t - on_s - 60.0 * m)))
            if abs(t[i] - on_s - 60.0 * m) > 5.0:
                continue
            r = self.rows[i]
            own = float(np.hypot(*(r["est_err_ne_m"] - r["ref_err_ne_m"])))
            we, wm, ws = r["wind_err_ne_mps"], r["wind_est_ne_mps"], r["wind_sigma_ne_mps"]
            out.append(f"  {m:5.1f} | {own:6.0f} / {r['h_acc_m']:5.0f} / {r['unaided_h_m']:5.0f} | {np.hypot(*r['ref_err_ne_m']):6.0f} / "
                       f"{np.hypot(*r['est_err_ne_m']):6.0f} | {we[0]:+5.2f},{we[1]:+5.2f} / {wm[0]:+5.2f},{wm[1]:+5.2f} "
                       f"+- {ws[0]:.2f},{ws[1]:.2f} | {math.degrees(r['heading_err_rad']):+5.1f} / "
                       f"{math.degrees(r['heading_est_rad']):+5.1f} +- {math.degrees(r['heading_sigma_rad']):.1f} | "
                       f"{r['status']} | {np.nanmean(nis[since]) if since.any() else math.nan:.3f}")
        return out
