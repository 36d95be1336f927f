"""Differences between a real log and its simulation that are not receiver effects (DESIGN 7.2):
named as such and measured, so that no effect of section 6 absorbs them.

- ``georeference_model``: a profile that converts scene metres to degrees by the paper's
  flat-earth rule misplaces the simulated antenna by a distance that grows with the run's
  distance from the scene origin (metres at a few kilometres, tens of metres at 25 km). It is
  computed exactly along each run's truth.
- ``truth_offset``: the truth itself sits off the antenna (a map-picked point, a lever arm, a
  datum): a constant error that time blocks separated by the error's correlation time all
  share, while a receiver's slow error changes direction from block to block. Tested per run
  with Hotelling's T^2 on the blocks' mean errors, less the seeds' own and less the fixes' lag
  behind a moving truth, its null calibrated on the seeds themselves, at :data:`OFFSET_P`;
  where it holds and exceeds :data:`OFFSET_MIN_M`, the real errors are taken about the truth
  moved by the estimate before anything else is judged. For a flat-earth profile it is tested
  against the conversion the log follows (:func:`truth_offset_of`), so the profile's own
  misplacement of the antenna is never taken for an offset of the truth.
- ``constellations``: the real receiver tracks satellite systems the simulation does not (a
  phone's GLONASS beside GPS): satellites used, HDOP and tracking then differ for that reason,
  which no effect of a GPS receiver explains. Counted per run from the log's GSV and GSA.
- ``sky``: the log's GSV puts satellites where the ephemeris does not (an ephemeris of another
  time, a truth on another date or in another place, a satellite relocated or renumbered since
  the TLE set): those satellites are left out of the tracking comparisons
  (:data:`virtualgps.gap.runs.SKY_SEP_MAX_DEG`), so that no sky mask or elevation mask is
  fitted to a sky that is not the log's.
- ``time_offset``: a log-vs-truth clock offset moves every fix along the track by speed x
  offset. Beyond the ingest's threshold it is removed there; below it, it is measured per block
  (with an interval) and reported: an output latency looks exactly the same in positions, so
  when ``latency`` is added the report says that a clock offset of the same size would too.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
from scipy import special

from virtualgps import geodesy
from virtualgps.gap.bands import METRICS
from virtualgps.gap.motion import fix_lag_s, lag_s
from virtualgps.gap.runs import Run
from virtualgps.gap.where import MOVING_MPS, errors_enu
from virtualgps.sky import systems
from virtualgps.sky.broadcast import gps_minus_utc_s

OFFSET_P = 0.01  # a truth offset is named at this level (it moves the truth for the rest)
OFFSET_MIN_M = 1.0  # and only when larger than this
MIN_OFFSET_BLOCKS = 4  # Hotelling's T^2 in 2 dimensions with n - 2 >= 2 degrees of freedom
MIN_CALIBRATION_SEEDS = 8  # seeds that calibrate its null (fewer: taken as independent)
GEOREF_MIN_M = 0.5  # a flat-earth misplacement below this is no cause (the print resolution)
LAG_MIN_MOVING = 30  # moving epochs a block needs for its lag


def _blocks(t: np.ndarray, ok: np.ndarray, length_s: float) -> list[np.ndarray]:
    """Blocks of ``length_s`` separated by gaps of ``length_s`` over the epochs ``ok``."""
    tv = t[ok]
    if tv.size < 2 or not length_s > 0:
        return []
    n = int(math.floor((tv[-1] - tv[0] + length_s) / (2.0 * length_s)))
    return [ok & (t >= tv[0] + 2 * b * length_s) & (t < tv[0] + (2 * b + 1) * length_s)
            for b in range(n)]


def flat_earth_enu_m(run: Run) -> np.ndarray:
    """Where the paper's flat-earth conversion puts the simulated antenna, from the run's truth.

    Returns
    -------
    (n, 3) east, north, up of the flat-earth antenna about the truth at each epoch, metres (NaN
    where the run has no valid truth)
    """
    s, v = run.setup, run.view
    ok = s.valid
    out = np.full((ok.size, 3), np.nan)
    if not ok.any():
        return out
    g = s.georef
    lat, lon = geodesy.flat_earth_to_geodetic(s.antenna_enu_m[ok, 0], s.antenna_enu_m[ok, 1],
                                              g.lat0_deg, g.lon0_deg)
    alt = g.alt0_hae_m + s.antenna_enu_m[ok, 2]
    out[ok] = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(lat, lon, alt),
                                  v.truth_lat_deg[ok], v.truth_lon_deg[ok],
                                  v.truth_alt_hae_m[ok])
    return out


def georeference(runs: list[Run], georef_model: str) -> dict | None:
    """How far the profile's flat-earth conversion puts the simulated antenna from the truth,
    per run (None for a profile with the exact WGS-84 conversion, or where it stays below
    GEOREF_MIN_M)."""
    if georef_model != "flat_earth":
        return None
    per_run = {}
    for r in runs:
        ok = r.setup.valid
        if not ok.any():
            continue
        e = flat_earth_enu_m(r)[ok]
        d = np.hypot(e[:, 0], e[:, 1])
        reach = np.hypot(r.setup.antenna_enu_m[ok, 0], r.setup.antenna_enu_m[ok, 1])
        per_run[r.view.name] = {"median_m": float(np.median(d)), "max_m": float(np.max(d)),
                                "up_max_m": float(np.max(np.abs(e[:, 2]))),
                                "farthest_from_origin_m": float(reach.max())}
    if not per_run or max(p["max_m"] for p in per_run.values()) < GEOREF_MIN_M:
        return None
    worst = max(per_run.values(), key=lambda p: p["max_m"])
    return {"name": "georeference_model", "kind": "simulation",
            "what": "the profile converts scene metres to degrees by the paper's flat-earth "
                    "rule (georef = \"flat_earth\"): along these runs it puts the simulated "
                    f"antenna up to {worst['max_m']:.1f} m from the truth (median "
                    f"{worst['median_m']:.1f} m), {worst['up_max_m']:.1f} m in height, "
                    f"{worst['farthest_from_origin_m'] / 1000:.1f} km from the scene origin",
            "per_run": per_run}


def truth_offset_of(run: Run, corr_time_s: float, sim_err_enu_m: np.ndarray,
                    georef_model: str) -> dict | None:
    """:func:`truth_offset` against the conversion the real log follows.

    For a profile with the paper's flat-earth conversion the simulated errors hold its
    misplacement of the antenna (tens of metres on a drive 25 km from the scene origin), which
    a real receiver's fixes do not: judged against them, the GSDC drive's truth (NovAtel SPAN,
    right to centimetres) was "29 m off" and moved, and the phone's 0.8 m CEP50 became 28.6 m.
    So the offset is tested twice, against the simulated errors as they are and against them
    less the flat-earth misplacement (:func:`flat_earth_enu_m`: what the exact conversion
    gives), and the reference under which the real log's block means lie nearest the truth
    (the smaller ``rms_m``: the conversion that explains the log with the least offset of the
    truth) is kept; its ``reference`` says which ("flat_earth" or "wgs84"). A log made by the
    flat-earth rule itself (the paper's simulator) keeps it. (Not the smaller test
    statistic: against the wrong conversion the block means vary with the misplacement, and
    that spread weakens Hotelling's T^2, so the wrong one looked the more plausible.) Which
    conversion the profile should use is then the ``georeference_model`` cause's question,
    decided on held-out data.

    sim_err_enu_m : (s, n, 3) the profile's ensemble's errors along the run
    """
    own = truth_offset(run, corr_time_s, sim_err_enu_m)
    if georef_model != "flat_earth":
        return own if own is None else own | {"reference": "wgs84"}
    exact = truth_offset(run, corr_time_s, sim_err_enu_m - flat_earth_enu_m(run)[None])
    pick = [(o["rms_m"], ref, o) for ref, o in (("flat_earth", own), ("wgs84", exact))
            if o is not None]
    if not pick:
        return None
    _, ref, off = min(pick, key=lambda x: x[0])
    out = off | {"reference": ref}
    if own is not None and exact is not None:
        follows = ("the exact conversion, which the log follows better than the profile's "
                   "flat-earth one" if ref == "wgs84" else "the profile's flat-earth "
                   "conversion, which the log follows better than the exact one")
        out["reference_note"] = (f"measured against {follows} (its block means "
                                 f"{off['rms_m']:.1f} m from the truth against "
                                 f"{(own if ref == 'wgs84' else exact)['rms_m']:.1f} m)")
    return out


def truth_offset(run: Run, corr_time_s: float, sim_err_enu_m: np.ndarray) -> dict | None:
    """Test a constant offset between one run's truth and its antenna (see the module
    docstring): the real errors' block means less the simulated ones' (the median over seeds:
    what the profile's own model does on that path, such as the paper's flat-earth
    conversion, is no offset of the truth).

    Hotelling's T^2 assumes independent block means, which a receiver's slow error breaks: a
    range error of 230 s correlation shows a 1/e time of about 60 s in a 15-minute run, and
    blocks that far apart still share it (logs made by ``holux-m1000`` itself then gave
    p < 0.01 for one run in eight). So the statistic is calibrated on the seeds along the same
    path, each taken as the real log against the others' median: T^2 is divided by the
    seeds' inflation, their median T^2 over the F distribution's median (at least 1), before
    its p-value is read, and the interval is widened by its square root.

    Parameters
    ----------
    run : the run; corr_time_s : its error's correlation time (the blocks' length and gap)
    sim_err_enu_m : (s, n, 3) the profile's ensemble's errors along the run

    Returns
    -------
    {"name": "truth_offset", "run", "east_m", "north_m" (the antenna's offset from the truth,
    which moving the truth by it removes), "interval_m", "p_value", "rms_m" (the root mean
    square of the blocks' mean real-less-simulated errors: how far the truth sits from the
    antenna on average, offset and all), "inflation", "blocks", "applied"} where it could be
    tested, else None
    """
    v = run.view
    if v.reference != "truth":
        return None
    e = run.err_real[0]
    ok = v.valid & np.isfinite(e[:, :2]).all(axis=1)
    if not math.isfinite(corr_time_s):
        return None  # correlated over the whole run: no independent blocks to compare
    length = max(30.0, corr_time_s)
    bl = [m for m in _blocks(v.t_unix_s, ok, length) if m.sum() >= 10]
    n = len(bl)
    if n < MIN_OFFSET_BLOCKS:
        return None
    # A lag behind a moving truth biases each block by -L times its mean velocity: it is
    # removed first (the lag is a cause of its own), so that a delay on a drive heading one
    # way is not taken for an offset.
    moving = v.valid & (v.speed_mps >= MOVING_MPS)
    real = _block_means(e[None, :, :2] + _lag_part(run.err_real, v.vel_enu_mps, moving), bl)[0]
    sim = _block_means(sim_err_enu_m[:, :, :2] + _lag_part(sim_err_enu_m, v.vel_enu_mps,
                                                           moving), bl)
    means = real - np.nan_to_num(np.nanmedian(sim, axis=0))
    stat = _hotelling(means)
    if stat is None:
        return None
    mean, cov, t2 = stat
    inflation = _inflation(sim, n)
    f = (n - 2) / (2.0 * (n - 1)) * t2 / inflation
    p = float(special.fdtrc(2, n - 2, f))
    half = float(special.stdtrit(n - 1, 0.975)) * np.sqrt(np.diag(cov) * inflation / n)
    size = float(np.hypot(*mean))
    return {"name": "truth_offset", "kind": "truth", "run": v.name,
            "east_m": float(mean[0]), "north_m": float(mean[1]), "size_m": size,
            "interval_m": {"east": [float(mean[0] - half[0]), float(mean[0] + half[0])],
                           "north": [float(mean[1] - half[1]), float(mean[1] + half[1])]},
            "p_value": p, "rms_m": float(np.sqrt(np.mean(np.sum(means ** 2, axis=1)))),
            "inflation": inflation, "blocks": n, "block_s": length,
            "applied": bool(p < OFFSET_P and size > OFFSET_MIN_M)}


def _block_means(err_en_m: np.ndarray, blocks: list[np.ndarray]) -> np.ndarray:
    """(s, b, 2) the mean horizontal error of each seed in each block (NaN where none)."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (a seed without a fix in a block)
        return np.stack([np.nanmean(err_en_m[:, m], axis=1) for m in blocks], axis=1)


def _hotelling(means: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Hotelling's one-sample T^2 that (b, 2) block means average zero: (mean, covariance,
    T^2), None where the covariance is singular or a block has no mean."""
    if not np.isfinite(means).all():
        return None
    mean = means.mean(axis=0)
    cov = np.cov(means, rowvar=False)
    try:
        return mean, cov, float(means.shape[0] * mean @ np.linalg.solve(cov, mean))
    except np.linalg.LinAlgError:
        return None


def _inflation(sim_means: np.ndarray, n: int) -> float:
    """How much larger T^2 runs under the profile's own errors than Hotelling's distribution
    says: the median T^2 of the seeds (each against the others' median) over that
    distribution's median; 1 with fewer than MIN_CALIBRATION_SEEDS usable seeds."""
    s = sim_means.shape[0]
    t2 = []
    for i in range(s):
        rest = np.delete(sim_means, i, axis=0)
        stat = _hotelling(sim_means[i] - np.nanmedian(rest, axis=0))
        if stat is not None:
            t2.append(stat[2])
    if len(t2) < MIN_CALIBRATION_SEEDS:
        return 1.0
    t2_median = 2.0 * (n - 1) / (n - 2) * float(special.fdtri(2, n - 2, 0.5))
    return max(1.0, float(np.median(t2)) / t2_median)


def _lag_part(err_enu_m: np.ndarray, vel_enu_mps: np.ndarray, moving: np.ndarray
              ) -> np.ndarray:
    """(s, n, 2) per seed, L times the truth's velocity, L that seed's least-squares lag over
    the moving epochs (0 with fewer than LAG_MIN_MOVING of them)."""
    if moving.sum() < LAG_MIN_MOVING:
        return np.zeros((err_enu_m.shape[0], err_enu_m.shape[1], 2))
    lag = np.nan_to_num(lag_s(err_enu_m, vel_enu_mps, moving))
    return lag[:, None, None] * np.nan_to_num(vel_enu_mps[None, :, :2])


def shift_truth(run: Run, east_m: float, north_m: float) -> Run:
    """The run with its real errors taken about the truth moved by (east, north) metres (onto
    the antenna, for a :func:`truth_offset`). The view keeps the truth the simulation runs
    along: the simulated errors stay about it (a few metres move no satellite)."""
    v = run.view
    lat, lon = geodesy.offset_geodetic_deg(v.truth_lat_deg, v.truth_lon_deg,
                                           np.nan_to_num(v.truth_alt_hae_m), east_m, north_m)
    moved = replace(v, truth_lat_deg=np.where(v.valid, lat, np.nan),
                    truth_lon_deg=np.where(v.valid, lon, np.nan))
    return replace(run, err_real=errors_enu(moved, v.real))


# A clock offset this close to GPS - UTC (seconds) is named as that: a time stamped in GPS time
# and read as UTC (the usual slip with a GNSS/INS truth), or a receiver printing GPS time. The
# ingest places an offset to about 0.01 s on a drive (GSDC: 18.01 s for 18 s); a receiver's own
# output latency, up to a few tenths of a second, adds to it.
LEAP_MATCH_S = 0.5


def clock_note(cause: dict) -> str | None:
    """What a ``time_offset`` cause says of a log-vs-truth clock offset found and taken out at
    ingest (beyond :data:`~virtualgps.gap.ingest.LATENCY_LIKE_S`), None where none was."""
    off = cause.get("applied_s") or 0.0
    if not off:
        return None
    side = "behind" if off < 0 else "ahead of"
    said = (f"the clock of {cause['run']}'s log runs {abs(off):.2f} s {side} its truth's: "
            "taken out before judging")
    leap = cause.get("gps_minus_utc_s")
    if leap and abs(abs(off) - leap) <= LEAP_MATCH_S:
        said += (f"; {leap:.0f} s is GPS time minus UTC on that day (the leap seconds): "
                 f"the {'truth' if off < 0 else 'log'}'s times are likely GPS time read as UTC")
    return said


# The receiver effects that make fixes lag their truth (DESIGN 7.5): what a time_offset cause's
# lag was read as, once the diagnosis has chosen
LAG_EFFECTS = ("latency", "nav_filter")


def lags_motion(entry: dict) -> bool:
    """Whether an added effect (a report entry) makes the fixes lag the truth's motion:
    ``latency``, and a ``nav_filter`` that low-passes the position itself. A velocity-aided
    filter follows the motion with the receiver's own velocity and smooths only the error
    (receiver/params.py, NavFilterParams): it explains smooth fixes, not a lag."""
    return entry["name"] == "latency" or (
        entry["name"] == "nav_filter" and not entry.get("params", {}).get("velocity_aided"))


def lag_reading(cause: dict) -> str:
    """What a ``time_offset`` cause's lag was read as, by the lag effects the diagnosis added
    (its ``read_as``, set with the report; ``or_read_as``: those of an equally good
    explanation, where they differ): a filter smooths the fixes as well, which a clock offset
    does not; a pure delay and a clock offset cannot be told apart."""
    taken = cause.get("read_as")
    if taken == ["nav_filter"]:
        said = ("read as a navigation filter's lag: nav_filter was added, the fixes being "
                "smoothed as well, which a clock offset does not do")
    elif taken == ["latency"]:
        said = ("read as an output latency (latency was added); a log-vs-truth clock offset "
                "of the same size moves the fixes alike: check both clocks")
    elif taken:
        said = "read as " + " and ".join(taken) + " together (both were added)"
    elif taken is not None:  # (the diagnosis chose, and added none of them)
        said = ("a clock offset or an output latency: no effect that lags the fixes was "
                "added")
    else:
        said = "a clock offset or an output latency"
    other = cause.get("or_read_as") or []
    if other:
        said += (" (or as " + " and ".join(other) + ": an equally good explanation, see "
                 "alternative)")
    return said


def _signed_lag_s(run: Run, epochs: np.ndarray) -> float:
    """The real fixes' lag behind the truth over some epochs, seconds, as the ``lag_s`` metric
    measures it (:func:`~virtualgps.gap.motion.fix_lag_s`); where that stays under the
    metric's floor (the fit of the steps stops at a lag of 0), the least-squares lag on the
    levels, which can be negative: a log ahead of its truth."""
    v = run.view
    lag = float(fix_lag_s(run.err_real, v.vel_enu_mps, v.truth_lat_deg, v.truth_lon_deg,
                          v.t_unix_s, epochs, ~v.near_building)[0])
    if math.isfinite(lag) and lag >= METRICS["lag_s"].floor:
        return lag
    return float(lag_s(run.err_real, v.vel_enu_mps, epochs)[0])


def time_offset(run: Run, corr_time_s: float) -> dict | None:
    """The log-vs-truth lag of one moving run: the ingest's estimate (median distance over
    +-30 s, widened to +-600 s while its best lies at the end), and the lag of the fixes
    behind the truth (:func:`_signed_lag_s`) over the run and per block, with a 95 % interval
    over blocks (None where the truth does not move, or moves at one velocity)."""
    v = run.view
    info = run.info.get("offset", {})
    moving = v.valid & (v.speed_mps >= MOVING_MPS)
    if moving.sum() < LAG_MIN_MOVING:
        return None
    length = max(60.0, corr_time_s if math.isfinite(corr_time_s) else 60.0)
    bl = [m for m in _blocks(v.t_unix_s, moving, length) if m.sum() >= LAG_MIN_MOVING]
    lags = np.array([_signed_lag_s(run, m) for m in bl])
    lags = lags[np.isfinite(lags)]
    whole = _signed_lag_s(run, moving)
    if not math.isfinite(whole):  # a truth at constant velocity: a lag is a bias there
        return None
    out = {"name": "time_offset", "kind": "clock", "run": v.name, "lag_s": whole,
           "blocks": int(lags.size), "interval_s": [math.nan, math.nan],
           "ingest_best_s": info.get("best_s"), "applied_s": run.info.get("time_offset_s", 0.0),
           "gps_minus_utc_s": float(gps_minus_utc_s(v.t_unix_s[0])),
           "what": "the fixes lag the truth by this much: a log-vs-truth clock offset and a "
                   "receiver's output latency move the fixes alike, and positions alone cannot "
                   "tell them apart"}
    if lags.size >= 3:
        half = float(special.stdtrit(lags.size - 1, 0.975)) * float(np.std(lags, ddof=1)) \
            / math.sqrt(lags.size)
        out["interval_s"] = [float(lags.mean() - half), float(lags.mean() + half)]
    return out


def constellations(name: str, prn: np.ndarray, in_view: np.ndarray, used: np.ndarray,
                   simulated: str) -> dict | None:
    """The satellite systems a real log tracks that the simulation lacks (None: none).

    prn : (k,) the log's satellite numbers (GSV/GSA IDs: GPS 1-32, GLONASS 65-96, ...)
    in_view, used : (n, k) bool, listed in GSV, listed in GSA, per epoch
    simulated : RINEX letters of the systems the simulation has (e.g. "G")
    """
    letters = systems.letters(prn)
    extra = {}
    for letter in sorted(set(letters.tolist()) - set(simulated) - {"?"}):
        cols = letters == letter
        seen = in_view[:, cols].sum(axis=1)
        used_n = used[:, cols].sum(axis=1)
        listed = seen > 0
        if listed.any():
            extra[systems.system_named(letter).name] = {
                "in_view_median": float(np.median(seen[listed])),
                "used_median": float(np.median(used_n[listed])),
                "epochs_share": float(listed.mean())}
    if not extra:
        return None
    what = ", ".join(f"{k} (median {v['in_view_median']:g} in view, {v['used_median']:g} used)"
                     for k, v in extra.items())
    return {"name": "constellations", "kind": "receiver", "run": name, "systems": extra,
            "simulated": [systems.system_named(x).name for x in simulated],
            "what": f"the real receiver also tracks {what}, which the simulation does not: "
                    "satellites used, HDOP and tracking differ for that reason; the "
                    "constellations effect is tried where the ephemeris holds their satellites "
                    "(--tle with a set of each system)"}


def sky(run: Run) -> dict | None:
    """The satellites a run's log puts elsewhere than the ephemeris does (None: none, or no GSV
    angles; :func:`virtualgps.gap.runs.prepare_runs` leaves them out of the comparisons). Most
    of a system's: that system's simulated sky is not the log's and none of its satellites'
    tracking is compared; a few: those satellites are not (relocated or renumbered since the
    TLE set)."""
    info = run.info.get("sky") or {}
    off = info.get("misplaced_prns") or []
    if not off:
        return None
    n, wrong = info["prns_compared"], info["wrong"]
    head = (f"the log's satellites stand a median {info['median_sep_deg']:g} deg from where "
            f"the ephemeris puts them ({len(off)} of {n} more than {info['max_sep_deg']:g} deg "
            f"off): the simulated {' and '.join(wrong)} sky is not the log's (an ephemeris of "
            "another time, a truth on another date or in another place, a system's numbering); "
            "none of its satellites' tracking is compared: --tle with a set of the log's day "
            "(or its RINEX navigation file) would compare them" if wrong else
            f"PRN {', '.join(str(p) for p in off)} stand more than {info['max_sep_deg']:g} deg "
            "from where the ephemeris puts them (relocated or renumbered since the TLE set): "
            "left out of the tracking comparisons")
    return {"name": "sky", "kind": "ephemeris", "run": run.view.name, "most": bool(wrong),
            "systems_wrong": wrong, "misplaced_prns": off, "prns_compared": n,
            "median_sep_deg": info["median_sep_deg"], "what": head}


def sky_wrong(causes: list[dict]) -> str | None:
    """Why no effect that acts on where satellites stand is tried (some run's simulated sky is
    not its log's: :func:`sky`), or None."""
    wrong = [c["run"] for c in causes if c["name"] == "sky" and c["most"]]
    if not wrong:
        return None
    return (f"the simulated sky is not the log's ({', '.join(wrong)}: see causes: sky): fitted "
            "to it, an effect placed on the sky would explain that sky, not the receiver")
