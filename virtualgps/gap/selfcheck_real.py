"""Real-log bases for the self-check (DESIGN 7.4): a real receiver's log with a known effect
injected into it, diagnosed like any other log.

The base is the GSDC 2020-05-14 drive (a Pixel 4's fixes with the NovAtel SPAN truth, from
``../shared/data``), diagnosed against ``holux-m1000``. The untouched log is diagnosed first:
what it already finds is the base's own gap (a phone is not a Holux). Then, per trial, one
change a real receiver or a real set-up makes is applied to the log's fixes (or to the truth),
at drawn parameters:

- ``latency``: every fix reports where the antenna was L seconds earlier (a pure output delay);
- ``nav_filter``: the fixes pass a first-order low-pass filter of time constant tau;
- ``static_hold``: the fix is frozen while the log's own speed is below a threshold;
- ``truth_offset``: the truth is moved by several metres (a wrong truth);
- ``cold_start``: the log's first T seconds print no fix (GGA quality 0, RMC void), as a
  receiver powered on with the log that needs T seconds for its first fix;
- ``correlated_error``: a slow offset, a first-order Gauss-Markov process of time constant tau
  and a drawn sigma per horizontal axis, is added to every fix. ``holux-m1000`` already has
  a correlated error, so this trial (and its untouched log) is diagnosed against it with that
  effect withheld (DESIGN 7.4).

A trial is right when the injected effect is the first effect added that the untouched log did
not add (or, for one it added too, when the new fit's interval holds the injected value), and
for the wrong truth when the diagnosis names a truth offset that lies within its uncertainty
(and the untouched log's) of the injected one plus the untouched log's own, and adds no effect
the untouched log did not.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from virtualgps import geodesy
from virtualgps.device.nmea import nmea_checksum, read_text_lines
from virtualgps.gap import diagnose as dg
from virtualgps.gap import effects as fx
from virtualgps.gap.ingest import read_real_log
from virtualgps.poses import logs as pose_logs
from virtualgps.poses import pose

GSDC = "gsdc-2020-05-14-mtv"
BASE_LOG = "Pixel4_chipset.nmea"  # (the drive's other phone, Pixel4XLModded_chipset.nmea, too)
BASE_PROFILE = "holux-m1000"
REAL_EFFECTS = ("latency", "nav_filter", "static_hold", "truth_offset", "cold_start",
                "correlated_error")
LABEL = "real:gsdc:"  # a trial's label: this and the effect injected


def named_effects(names: tuple[str, ...] | None) -> tuple[str, ...]:
    """The real-log trials a self-check asked for by ``names`` (its ``--effects``): all of
    :data:`REAL_EFFECTS` when it names none, else those named by their label
    (``real:gsdc:latency``). An unknown one raises ValueError."""
    if not names:
        return REAL_EFFECTS
    known = {LABEL + e: e for e in REAL_EFFECTS}
    asked = [n for n in names if n.startswith("real:")]
    bad = [n for n in asked if n not in known]
    if bad:
        raise ValueError(f"unknown real-log trial {', '.join(bad)}; known: "
                         f"{', '.join(known)}")
    return tuple(known[n] for n in asked)


# The tables that withhold an injected effect the base profile has (DESIGN 7.4)
WITHHOLD = {"correlated_error": {"correlated_error": {"enabled": False}}}
MPS_PER_KNOT = 1852.0 / 3600.0


def _tod_s(hhmmss: str) -> float:
    return int(hhmmss[:2]) * 3600.0 + int(hhmmss[2:4]) * 60.0 + float(hhmmss[4:])


def _fmt_minutes(value_deg: float, deg_digits: int, decimals: int) -> tuple[str, str]:
    """A coordinate as NMEA ``(d)ddmm.mmmm`` with the hemisphere's sign left to the caller."""
    a = abs(value_deg)
    d = int(a)
    m = round((a - d) * 60.0, decimals)
    if m >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{deg_digits}d}{m:0{3 + decimals}.{decimals}f}", ""


def _edit_sentences(lines: list[str], edit: Callable[[list[str]], bool]) -> list[str]:
    """The log's lines with each sentence's fields passed to ``edit`` (which changes them in
    place and says whether it did; those sentences are written again with their checksum
    recomputed, the others kept as they were)."""
    out = []
    for ln in lines:
        body = ln.strip()
        if not body.startswith("$") or "*" not in body:
            out.append(ln)
            continue
        f = body[1:body.rindex("*")].split(",")
        if not edit(f):
            out.append(ln)
            continue
        text = ",".join(f)
        out.append(f"${text}*{nmea_checksum(text)}")
    return out


def rewrite_fixes(lines: list[str], t_unix_s: np.ndarray, lat_deg: np.ndarray,
                  lon_deg: np.ndarray) -> list[str]:
    """The log's lines with the GGA and RMC positions of each epoch replaced (matched by the
    sentence's time of day), in the log's own digits, checksums recomputed.

    t_unix_s, lat_deg, lon_deg : (n,) the new position of each epoch
    """
    by_tod = {round(float(t) % 86400.0, 2): (a, b) for t, a, b in zip(t_unix_s, lat_deg,
                                                                        lon_deg, strict=True)}

    def move(f: list[str]) -> bool:
        pos = {"GGA": 2, "RMC": 3}.get(f[0][-3:])
        if pos is None or not f[1] or not f[pos]:
            return False
        new = by_tod.get(round(_tod_s(f[1]), 2))
        if new is None or not np.isfinite(new[0]):
            return False
        dec = len(f[pos].split(".")[1]) if "." in f[pos] else 4
        f[pos] = _fmt_minutes(new[0], 2, dec)[0]
        f[pos + 1] = "N" if new[0] >= 0 else "S"
        f[pos + 2] = _fmt_minutes(new[1], 3, dec)[0]
        f[pos + 3] = "E" if new[1] >= 0 else "W"
        return True

    return _edit_sentences(lines, move)


def blank_fixes(lines: list[str], start_unix_s: float, seconds: float) -> list[str]:
    """The log's lines with every GGA and RMC of its first ``seconds`` printed as a receiver
    without a fix prints them (GGA quality 0 with no position, satellites, HDOP or altitude;
    RMC status V with no position, speed or course), checksums recomputed.

    start_unix_s : the log's first epoch (its sentences carry the time of day: a sentence is
    ``seconds`` or more after it modulo a day, so a log over midnight is read right)
    """
    start_tod = start_unix_s % 86400.0

    def blank(f: list[str]) -> bool:
        kind = f[0][-3:]
        if (kind not in ("GGA", "RMC") or len(f) < 10 or not f[1]
                or (_tod_s(f[1]) - start_tod) % 86400.0 >= seconds):
            return False
        if kind == "GGA":
            f[2:10] = ["", "", "", "", "0", "", "", ""]
        else:
            f[2:9] = ["V", "", "", "", "", "", ""]
            if len(f) > 12:
                f[12] = "N"  # (the mode indicator: no fix)
        return True

    return _edit_sentences(lines, blank)


def _enu(lat, lon, lat0, lon0):
    e = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(lat, lon, np.zeros_like(lat)), lat0, lon0,
                            0.0)
    return e[:, :2]


def _geo(en, lat0, lon0):
    enu = np.column_stack([en, np.zeros(len(en))])
    lat, lon, _ = geodesy.ecef_to_geodetic(geodesy.enu_to_ecef(enu, lat0, lon0, 0.0))
    return lat, lon


def inject(effect: str, value: float, t: np.ndarray, lat: np.ndarray, lon: np.ndarray,
           speed_mps: np.ndarray, sigma_m: float = 4.0,
           rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The fixes a receiver with ``effect`` at ``value`` would have printed instead.

    t, lat, lon, speed_mps : (n,) the log's fixed epochs (time, position, its own speed)
    sigma_m, rng : ``correlated_error``'s sigma per horizontal axis (metres) and its draws
    """
    lat0, lon0 = float(lat[0]), float(lon[0])
    en = _enu(lat, lon, lat0, lon0)
    if effect == "latency":
        out = np.column_stack([np.interp(t - value, t, en[:, a]) for a in (0, 1)])
    elif effect == "nav_filter":
        out = en.copy()
        for k in range(1, t.size):
            a = math.exp(-(t[k] - t[k - 1]) / value)
            out[k] = a * out[k - 1] + (1 - a) * en[k]
    elif effect == "static_hold":
        out = en.copy()
        for k in range(1, t.size):
            if speed_mps[k] < value:
                out[k] = out[k - 1]
    elif effect == "correlated_error":
        rng = rng if rng is not None else np.random.default_rng()
        off = np.empty_like(en)
        off[0] = rng.normal(0.0, sigma_m, 2)
        for k in range(1, t.size):  # (stationary: the same sigma at any step)
            a = math.exp(-(t[k] - t[k - 1]) / value)
            off[k] = a * off[k - 1] + math.sqrt(1.0 - a * a) * sigma_m * rng.normal(size=2)
        out = en + off
    else:
        raise ValueError(effect)
    return _geo(out, lat0, lon0)


def _truth_jsonl(track: pose.PoseTrack, east_m: float, north_m: float, path: Path) -> None:
    lat, lon = geodesy.offset_geodetic_deg(track.xyz[:, 0], track.xyz[:, 1], track.xyz[:, 2],
                                           east_m, north_m)
    path.write_text("".join(json.dumps({"t": float(ti), "lat": float(a), "lon": float(b),
                                        "alt": float(h)}) + "\n"
                            for ti, a, b, h in zip(track.t_unix_s, lat, lon, track.xyz[:, 2],
                                                   strict=True)))


def _half(offset: dict, axis: str) -> float:
    """Half the width of a truth offset's 95 % interval on an axis (0 without one)."""
    iv = offset.get("interval_m", {}).get(axis)
    return (iv[1] - iv[0]) / 2.0 if iv else 0.0


def withheld_profile(effect: str, work: Path) -> str:
    """The profile an effect's trials are diagnosed against: :data:`BASE_PROFILE`, or where it
    has the effect, a copy with it withheld (written into ``work``; its path)."""
    if effect not in WITHHOLD:
        return BASE_PROFILE
    from virtualgps.receiver.profiles import profile_path, read_toml

    table = fx.apply(read_toml(profile_path(BASE_PROFILE)), WITHHOLD[effect])
    table["name"] = f"{BASE_PROFILE}-without-{effect}"
    path = work / f"{table['name']}.toml"
    path.write_text(fx.to_toml(table), encoding="utf-8")
    return str(path)


def run(data: Path, opts: dg.Options, trials: int, work: Path,
        progress: Callable[[str], None] | None = None,
        effects: tuple[str, ...] = REAL_EFFECTS,
        base_log: str = BASE_LOG) -> tuple[list[dict], str | None]:
    """The real-log trials of ``effects`` (of :data:`REAL_EFFECTS`) on the GSDC log
    ``base_log``: (rows for ``selfcheck.json``, a note when the data are missing)."""
    from virtualgps.gap import synthetic, tool

    d = Path(data) / GSDC
    real, truth = d / base_log, d / "SPAN_Pixel4_1Hz.nmea"
    tle = d / "gps-ops_2020-05-14T22Z.tle"
    if not (real.exists() and truth.exists() and tle.exists()):
        return [], f"real-log bases not run: {d} not found"
    work.mkdir(parents=True, exist_ok=True)

    def diagnose(real_path: Path, truth_spec: str, profile: str) -> dict:
        inp = tool.GapInputs(real=(str(real_path),), truth=(truth_spec,), scene="none",
                             tle=str(tle), profile=profile)
        return tool.diagnose(inp, opts)[0]

    bases: dict[str, tuple[list[str], dict]] = {}

    def untouched(profile: str) -> tuple[list[str], dict]:
        """What the untouched log adds against ``profile``, and its truth offset."""
        if profile not in bases:
            base = diagnose(real, str(truth), profile)
            bases[profile] = (
                [e["name"] for e in base["effects"] if e.get("accepted")],
                next((c for c in base.get("causes", []) if c["name"] == "truth_offset"), {}))
            if progress:
                progress(f"self-check real base gsdc against {Path(profile).stem}: the "
                         f"untouched log adds {bases[profile][0] or 'nothing'}")
        return bases[profile]

    ep, *_ = read_real_log(real)
    fix = (ep.quality > 0) & np.isfinite(ep.lat_deg)
    t, lat, lon = ep.t_unix_s[fix], ep.lat_deg[fix], ep.lon_deg[fix]
    speed = np.nan_to_num(ep.speed_mps[fix])
    lines = read_text_lines(real)
    track = pose_logs.read_pose_log(truth)
    rows = []
    for effect in effects:
        profile = withheld_profile(effect, work)
        base_added, base_off = untouched(profile)
        for i in range(trials):
            rng = np.random.default_rng([synthetic.SEED_BASE, 77, REAL_EFFECTS.index(effect), i])
            tag = f"real-gsdc-{effect}-{i}"
            if effect == "truth_offset":
                ang = rng.uniform(0, 2 * np.pi)
                size = round(float(rng.uniform(5.0, 10.0)), 1)
                east, north = size * math.sin(ang), size * math.cos(ang)
                tpath = work / f"{tag}-truth.jsonl"
                _truth_jsonl(track, east, north, tpath)
                report = diagnose(real, str(tpath), profile)
                injected = {"east_m": round(east, 2), "north_m": round(north, 2)}
                off = next((c for c in report.get("causes", []) if c["name"] == "truth_offset"),
                           None)
                # The truth moved by +d: the fixes lie -d from it, plus the untouched log's own
                # offset from its truth (a phone's bias): held when the estimate lies within
                # the two estimates' 95 % half-widths of that.
                held = off is not None and off["applied"] and all(
                    abs(off[f"{ax}_m"] - (-v + base_off.get(f"{ax}_m", 0.0)))
                    <= _half(off, ax) + _half(base_off, ax)
                    for ax, v in (("east", east), ("north", north)))
                added = [e["name"] for e in report["effects"] if e.get("accepted")]
                success = bool(held and set(added) <= set(base_added))
                recovered = ({"east_m": -off["east_m"], "north_m": -off["north_m"]}
                             if off is not None else {})
            else:
                lo_hi = {"latency": (0.8, 2.5), "nav_filter": (1.5, 4.0),
                         "static_hold": (0.8, 1.5), "cold_start": (25.0, 60.0),
                         "correlated_error": (60.0, 600.0)}[effect]
                value = round(float(rng.uniform(*lo_hi)), 2)
                sigma = round(float(rng.uniform(2.5, 6.0)), 2)  # (correlated_error's)
                path = work / f"{tag}.nmea"
                if effect == "cold_start":  # (whole seconds: the log's epochs are 1 s apart)
                    value = float(round(value))
                    new_lines = blank_fixes(lines, float(ep.t_unix_s[0]), value)
                else:
                    nlat, nlon = inject(effect, value, t, lat, lon, speed, sigma, rng)
                    new_lines = rewrite_fixes(lines, t, nlat, nlon)
                path.write_text("\n".join(new_lines) + "\n")
                report = diagnose(path, str(truth), profile)
                key = {"latency": "latency_s", "nav_filter": "tau_s",
                       "static_hold": "threshold_mps", "cold_start": "ttff_cold_s",
                       "correlated_error": "tau_s"}[effect]
                injected = {key: value}
                added = [e["name"] for e in report["effects"] if e.get("accepted")]
                params, intervals, grids = synthetic.recovered((effect,), report)
                new = [a for a in added if a not in base_added]
                cov = synthetic.covered(injected, intervals, grids)
                success = bool((new and new[0] == effect)
                               or (effect in base_added and effect in added and cov.get(key)))
                recovered = params
            accepted = [e["name"] for e in report["effects"] if e.get("accepted")]
            ranked = [a for a in accepted if a not in base_added] or [synthetic.NOTHING]
            first = (("truth_offset" if success else ranked[0]) if effect == "truth_offset"
                     else ranked[0])
            rows.append({
                "injected": f"{LABEL}{effect}", "kind": "real", "effects": [effect],
                "scenario": f"gsdc drive, {Path(profile).stem}",
                "params": (injected | {"sigma_m": sigma} if effect == "correlated_error"
                           else injected),
                "ranked": ranked, "accepted": accepted, "base_accepted": base_added,
                "ranked_first": first, "added_first": ranked[0], "success": success,
                "alternative": (report.get("alternative") or {}).get("effects"),
                "recovered": recovered,
                "recovered_interval": ({} if effect == "truth_offset" else intervals),
                "covered": {} if effect == "truth_offset" else cov,
                **synthetic.report_fields(report),
                "real": str(real if effect == "truth_offset" else path),
                "truth": str(tpath if effect == "truth_offset" else truth),
            })
            if progress:
                progress(f"self-check real:gsdc:{effect} trial {i + 1}/{trials}: "
                         f"{'right' if success else 'wrong'} (new: {ranked})")
    return rows, None
