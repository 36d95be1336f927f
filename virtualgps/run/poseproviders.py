"""Where the live daemon's receivers are at each epoch: pose providers over a recorded track,
the bundled scene's demo lap, a live pose stream, or one per fleet member, and the simulated
clock that ticks them.
"""

from __future__ import annotations

import logging
import time
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from virtualgps.exceptions import PoseError
from virtualgps.poses import pose
from virtualgps.receiver.definition import Georef

log = logging.getLogger(__name__)

LIVE_POSE_HISTORY = 64  # poses kept for interpolation; a few seconds at typical robot rates


MAX_MESSAGES_PER_PUMP = 20_000  # bound the work between two epochs under a message flood


@dataclass
class SimClock:
    """Simulated UTC running at wall-clock speed from ``start_unix_s`` (or the wall clock itself).

    offset_s : simulated minus wall-clock time; poses stamped by the robot's (wall) clock are
        moved by it onto the simulated clock
    """

    start_unix_s: float | None = None
    _mono0: float = field(default_factory=time.monotonic)
    _wall0: float = field(default_factory=time.time)

    @property
    def offset_s(self) -> float:
        return 0.0 if self.start_unix_s is None else self.start_unix_s - self._wall0

    def now_unix_s(self) -> float:
        """Simulated UTC now, seconds."""
        base = self._wall0 if self.start_unix_s is None else self.start_unix_s
        return base + (time.monotonic() - self._mono0)

    @property
    def anchor(self) -> tuple[float, float]:
        """(monotonic, wall-clock) seconds at which this clock started: a clock made with them,
        ``SimClock(start_unix_s, *anchor)``, reads the same time in any process of the machine
        (the monotonic clock is the system's)."""
        return self._mono0, self._wall0

    def monotonic_at(self, t_unix_s: float) -> float:
        """The monotonic-clock time at which the simulated clock reads ``t_unix_s``."""
        base = self._wall0 if self.start_unix_s is None else self.start_unix_s
        return self._mono0 + (t_unix_s - base)


class PoseProvider(Protocol):
    """Where the daemon gets the antenna pose at an epoch."""

    def fileno_list(self) -> list[int]:
        """File descriptors to wait on for incoming poses (may be empty)."""
        ...

    def pump(self) -> None:
        """Read whatever has arrived (never blocks)."""
        ...

    def pose_at(
        self, t_unix_s: np.ndarray, receiver_id: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos (n, 3) scene ENU m, vel (n, 3) ENU m/s, valid (n,) bool) of a receiver at
        simulated times."""
        ...

    def close(self) -> None: ...


class _KnownPoses:
    """A provider whose poses are known in advance: nothing to wait for or read."""

    def fileno_list(self) -> list[int]:
        return []

    def pump(self) -> None:
        return None


class TrackProvider(_KnownPoses):
    """A pose log (or any PoseTrack in scene ENU) replayed in real time: its time
    ``t_first_unix_s`` (default: its first pose's) at simulated ``t0_unix_s``."""

    def __init__(self, track: pose.PoseTrack, t0_unix_s: float, max_gap_s: float,
                 t_first_unix_s: float | None = None) -> None:
        self.track = track
        if t_first_unix_s is None:
            t_first_unix_s = float(track.t_unix_s[0]) if len(track) else t0_unix_s
        self.shift_s = t0_unix_s - t_first_unix_s
        self.max_gap_s = max_gap_s

    def pose_at(
        self, t_unix_s: np.ndarray, receiver_id: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return pose.interpolate(self.track, np.asarray(t_unix_s) - self.shift_s, self.max_gap_s)

    def close(self) -> None:
        return None


def demo_lap(waypoints_enu_m: np.ndarray, speed_mps: float, step_s: float = 0.5) -> pose.PoseTrack:
    """One lap of a scripted walk: the closed waypoint loop at constant speed, sampled densely.

    Parameters
    ----------
    waypoints_enu_m : (n, 3) metres, scene ENU (antenna positions)
    speed_mps : walking speed
    step_s : sampling interval of the returned track

    Returns
    -------
    lap : PoseTrack in the scene ENU frame, times from 0 to the lap time; velocities are left
        to finite differences, which are exact since every corner is a sample
    """
    pts = np.asarray(waypoints_enu_m, dtype=float)
    loop = np.vstack([pts, pts[:1]])
    seg_m = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    leg_t = np.concatenate([[0.0], np.cumsum(seg_m) / speed_mps])  # (n + 1,) arrival times
    t = np.union1d(np.arange(0.0, leg_t[-1], step_s), leg_t)
    k = np.clip(np.searchsorted(leg_t, t, side="right") - 1, 0, len(seg_m) - 1)
    w = ((t - leg_t[k]) / (leg_t[k + 1] - leg_t[k]))[:, None]
    xyz = loop[k] + w * (loop[k + 1] - loop[k])
    return pose.PoseTrack(t_unix_s=t, frame="enu", xyz=xyz, vel_enu_mps=np.full_like(xyz, np.nan))


class LoopProvider(TrackProvider):
    """A lap (times from 0) walked again and again from ``t0_unix_s``: the ``demo`` source."""

    def __init__(self, lap: pose.PoseTrack, t0_unix_s: float, max_gap_s: float) -> None:
        super().__init__(lap, 0.0, max_gap_s)
        self.t0_unix_s = t0_unix_s
        self.lap_s = float(lap.t_unix_s[-1])

    def pose_at(
        self, t_unix_s: np.ndarray, receiver_id: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t_lap = (np.asarray(t_unix_s, dtype=float) - self.t0_unix_s) % self.lap_s
        return pose.interpolate(self.track, t_lap, self.max_gap_s)


class LiveProvider:
    """Poses from a message source (UDP, TCP, stdin): parsed, counted, kept for interpolation,
    one history per receiver (the message's ``"id"``, 0 where absent).

    Malformed messages are counted per kind and logged once per kind; messages for a receiver
    that does not exist are counted (``unknown_ids``) and logged once. Neither ever stops the
    daemon.

    Parameters
    ----------
    source : the message source (``poll``, ``fileno_list``, ``close``)
    georef : the scene's georeference (geodetic poses -> scene ENU)
    clock : the simulated clock (robot-clock times -> simulated times)
    max_gap_s : the pose timeout
    receiver_ids : the receivers that exist (default: receiver 0 alone)
    elsewhere_ids : receivers of the fleet that other hosts run (``--ids``): their messages
        are skipped and counted (``elsewhere``), not taken for unknown receivers
    """

    def __init__(self, source, georef: Georef, clock: SimClock, max_gap_s: float,
                 receiver_ids: Iterable[int] = (0,), elsewhere_ids: Iterable[int] = ()) -> None:
        self.source = source
        self.georef = georef
        self.clock = clock
        self.max_gap_s = max_gap_s
        self.histories: dict[int, deque[tuple[float, np.ndarray, np.ndarray]]] = {
            int(i): deque(maxlen=LIVE_POSE_HISTORY) for i in receiver_ids}
        self.bad: Counter[str] = Counter()
        self.unknown_ids: Counter[int] = Counter()
        self.elsewhere_ids = frozenset(int(i) for i in elsewhere_ids)
        self.elsewhere = 0
        self.n_good = 0
        self._tracks: dict[int, pose.PoseTrack] = {}

    @property
    def history(self) -> deque[tuple[float, np.ndarray, np.ndarray]]:
        """Receiver 0's poses (simulated time, ENU m, ENU m/s), oldest first."""
        return self.histories[min(self.histories)]

    def fileno_list(self) -> list[int]:
        return list(self.source.fileno_list())

    def _to_enu(self, p: pose.Pose) -> np.ndarray:
        if p.frame == "enu":
            return np.asarray(p.xyz, dtype=float)
        track = pose.PoseTrack(
            np.array([p.t_unix_s]),
            "geodetic",
            np.asarray([p.xyz], float),
            np.asarray([p.vel_enu_mps], float),
        )
        g = self.georef
        return pose.to_enu(track, g.lat0_deg, g.lon0_deg, g.alt0_hae_m).xyz[0]

    def pump(self) -> None:
        messages = self.source.poll()[:MAX_MESSAGES_PER_PUMP]
        for data, arrival_wall_s in messages:
            try:
                p = pose.parse_pose_message(data, arrival_wall_s)
                history = self.histories.get(p.receiver_id)
                if history is None:
                    if p.receiver_id in self.elsewhere_ids:
                        self.elsewhere += 1
                        continue
                    if not self.unknown_ids:
                        log.warning("skipping a pose message for receiver %d, which does not "
                                    "exist (further ones are counted, not logged)", p.receiver_id)
                    self.unknown_ids[p.receiver_id] += 1
                    continue
                enu = self._to_enu(p)
            except PoseError as exc:
                if self.bad[exc.kind] == 0:
                    log.warning(
                        "skipping malformed pose message (%s): %s "
                        "(further ones of this kind are counted, not logged)",
                        exc.kind,
                        exc,
                    )
                self.bad[exc.kind] += 1
                continue
            t_sim = p.t_unix_s + self.clock.offset_s
            if history and t_sim <= history[-1][0]:
                if t_sim == history[-1][0]:
                    continue
                # Out-of-order message: keep the history sorted (rare; UDP may reorder).
                items = sorted(
                    [*history, (t_sim, enu, np.asarray(p.vel_enu_mps, float))],
                    key=lambda item: item[0],
                )
                history.clear()
                history.extend(items[-LIVE_POSE_HISTORY:])
            else:
                history.append((t_sim, enu, np.asarray(p.vel_enu_mps, float)))
            self.n_good += 1
            self._tracks.pop(p.receiver_id, None)

    def poses_at(
        self, t_unix_s: float, receiver_ids: list[int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The poses of several receivers at one simulated time (see :func:`poses_at`): what
        :meth:`pose_at` gives each, to the bit. An epoch at or after a receiver's last pose (a
        live stream lags the clock) extrapolates that pose with its velocity (its own, else
        the last step's), all such receivers at once, as :func:`virtualgps.poses.pose.interpolate`
        does past a track's end; any other goes through :meth:`pose_at`.

        Returns
        -------
        pos : (n, 3) scene ENU m; vel : (n, 3) ENU m/s; valid : (n,) bool
        """
        n = len(receiver_ids)
        pos, vel, valid = np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
        after: list[int] = []
        tails = []
        for b, rid in enumerate(receiver_ids):
            h = self.histories.get(rid)
            if not h:
                continue
            if t_unix_s >= h[-1][0]:
                after.append(b)
                tails.append((h[-1], h[-2] if len(h) > 1 else h[-1]))
            else:
                pos[b], vel[b], valid[b] = (a[0] for a in self.pose_at(np.array([t_unix_s]), rid))
        if after:
            t_last = np.array([last[0] for last, _ in tails])
            t_prev = np.array([prev[0] for _, prev in tails])
            p_last = np.array([last[1] for last, _ in tails])
            p_prev = np.array([prev[1] for _, prev in tails])
            v_last = np.array([last[2] for last, _ in tails])
            with np.errstate(invalid="ignore", divide="ignore"):  # (one pose: no step)
                fd = (p_last - p_prev) / (t_last - t_prev)[:, None]
            last_v = np.where(np.isnan(v_last), np.where((t_last > t_prev)[:, None], fd, np.nan),
                              v_last)
            last_v = np.where(np.isnan(last_v), 0.0, last_v)
            age = t_unix_s - t_last
            ok = age <= self.max_gap_s
            pos[after] = np.where(ok[:, None], p_last + age[:, None] * last_v, np.nan)
            vel[after] = np.where(ok[:, None], last_v, np.nan)
            valid[after] = ok
        return pos, vel, valid

    def pose_at(
        self, t_unix_s: np.ndarray, receiver_id: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t_unix_s, dtype=float)
        history = self.histories.get(receiver_id)
        if not history:
            n = t.shape[0]
            return np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
        track = self._tracks.get(receiver_id)
        if track is None:
            ts, xyz, vel = zip(*history, strict=True)
            track = self._tracks[receiver_id] = pose.PoseTrack(
                np.array(ts), "enu", np.array(xyz), np.array(vel))
        return pose.interpolate(track, t, self.max_gap_s)

    def close(self) -> None:
        self.source.close()


class ReceiverPoses(_KnownPoses):
    """Each receiver's own provider (pose logs split by id, demo walks): ``pose_at`` by id.

    Parameters
    ----------
    providers : {receiver id: provider}; a receiver without one has no pose (no fix)
    """

    def __init__(self, providers: dict[int, PoseProvider]) -> None:
        self.providers = providers

    def poses_at(
        self, t_unix_s: float, receiver_ids: list[int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The poses of several receivers at one simulated time (see :func:`poses_at`); the
        demo's walkers, one lap at different phases, in one interpolation.

        Returns
        -------
        pos : (n, 3) scene ENU m; vel : (n, 3) ENU m/s; valid : (n,) bool
        """
        n = len(receiver_ids)
        pos, vel, valid = np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
        laps: dict[int, list[int]] = {}
        for b, rid in enumerate(receiver_ids):
            p = self.providers.get(rid)
            if isinstance(p, LoopProvider):
                laps.setdefault(id(p.track), []).append(b)
            elif p is not None:
                pos[b], vel[b], valid[b] = (a[0] for a in p.pose_at(np.array([t_unix_s]), rid))
        for idx in laps.values():
            ps = [self.providers[receiver_ids[b]] for b in idx]
            t_lap = np.array([(t_unix_s - p.t0_unix_s) % p.lap_s for p in ps])
            pos[idx], vel[idx], valid[idx] = pose.interpolate(ps[0].track, t_lap, ps[0].max_gap_s)
        return pos, vel, valid

    def pose_at(
        self, t_unix_s: np.ndarray, receiver_id: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = self.providers.get(receiver_id)
        if p is None:
            n = np.asarray(t_unix_s).shape[0]
            return np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
        return p.pose_at(t_unix_s, receiver_id)

    def close(self) -> None:
        for p in self.providers.values():
            p.close()
