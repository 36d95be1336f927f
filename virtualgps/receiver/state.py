"""What a receiver carries from one epoch to the next, and the random numbers it draws.

:class:`ReceiverState` is one receiver's state (time-correlated errors, tracking, start-up, the
output stage's memory, its models' random streams); :class:`ReceiverRows` the states of several
receivers simulated side by side (a fleet's tick); :func:`restart` and :func:`initial_state`
start one. :func:`draw_layout`, :func:`model_streams` and :func:`draw_uniforms` say which
uniforms each error model takes from which stream at every epoch, so that N epochs drawn at
once are the N epochs drawn one at a time. :func:`virtualgps.receiver.core.simulate` takes and
returns these states.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from virtualgps.receiver.params import Profile


@dataclass(frozen=True)
class ReceiverState:
    """What a receiver carries from one epoch to the next.

    The paper's model is memoryless; the state still travels through every call so that
    time-correlated effects (tracking, Gauss-Markov errors, start-up) slot in without reshaping.

    n_epochs : epochs simulated so far
    last_t_unix_s : time of the last simulated epoch (NaN before the first)
    no_fix_until_t_unix_s : no fix before this time (start-up: the time to first fix after the
        last restart; -inf when the receiver is not starting up)
    gm_m : (n_sat,) or (3,) float, metres, the Gauss-Markov errors (``correlated_error``) after
        the last epoch, None before the first
    last_alt_hae_m : altitude of the last 3D fix (a 2D fix holds it), NaN before the first
    nav_enu_m : (3,) the ``nav_filter`` output at the last epoch (its error where
        ``velocity_aided``; None: restart the filter)
    hold_enu_m : (3,) the position ``static_hold`` is holding (None: not holding)
    past_t_unix_s, past_enu_m : (m,) UTC seconds and (m, 3) metres, the truth's last known
        positions, as far back as ``latency`` reaches (None: none, or no ``latency``)
    usable_from_t_unix_s : (n_sat,) when each satellite's ephemeris is decoded after a start
        (None: all usable)
    start_bias_enu_m : (3,) metres, the start-up error that decays after the first fix
    fade_db, tracked, acq_run : (n_sat,) the ``cn0_tracking`` state: C/N0 fades (dB), tracked
        flags, epochs spent at or above the acquisition threshold; None before the first epoch
    mp_m : (n_sat,) float, the ``multipath`` Gauss-Markov processes (unit variance; scaled by
        each epoch's sigma) after the last epoch, None before the first
    rr_mps : (n_sat,) float, the Doppler range-rate Gauss-Markov processes (unit variance) after
        the last epoch, None before the first
    streams : {model: Generator}, the error models' own random streams (see
        :func:`model_streams`), made from the run's generator at its first epoch
    """

    n_epochs: int = 0
    last_t_unix_s: float = float("nan")
    no_fix_until_t_unix_s: float = float("-inf")
    gm_m: np.ndarray | None = field(default=None, compare=False)
    last_alt_hae_m: float = float("nan")
    nav_enu_m: np.ndarray | None = field(default=None, compare=False)
    hold_enu_m: np.ndarray | None = field(default=None, compare=False)
    past_t_unix_s: np.ndarray | None = field(default=None, compare=False)
    past_enu_m: np.ndarray | None = field(default=None, compare=False)
    usable_from_t_unix_s: np.ndarray | None = field(default=None, compare=False)
    start_bias_enu_m: np.ndarray | None = field(default=None, compare=False)
    fade_db: np.ndarray | None = field(default=None, compare=False)
    tracked: np.ndarray | None = field(default=None, compare=False)
    acq_run: np.ndarray | None = field(default=None, compare=False)
    mp_m: np.ndarray | None = field(default=None, compare=False)
    rr_mps: np.ndarray | None = field(default=None, compare=False)
    streams: dict | None = field(default=None, compare=False)


def history_len(profile: Profile) -> int:
    """How many of the truth's past positions a receiver side by side with others keeps for
    ``latency``: as many epochs at the profile's rate as reach ``latency_s`` back, and two
    more (0 without ``latency``)."""
    if not profile.latency.enabled:
        return 0
    return int(np.ceil(profile.latency.latency_s * profile.rate_hz - 1e-9)) + 2


START_KINDS = ("hot", "warm", "cold")
DRAW_AHEAD = 8  # epochs of uniforms that receivers side by side draw at once (ReceiverRows)


@dataclass
class _Ahead:
    """Uniforms :class:`ReceiverRows` drew ahead: per plan block an (n, k, width) array, of
    which ``used`` epochs are used; ``back`` the rows already given back; ``epochs`` the
    epochs the rows have drawn so far."""

    plan: tuple = ()
    blocks: list = field(default_factory=list)
    used: int = 0
    k: int = 0
    back: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    epochs: int = 0
    rewinds: bool | None = None  # whether every generator can step back (PCG64's advance)


@dataclass(frozen=True)
class ReceiverRows:
    """The states of several receivers simulated side by side, one epoch each (a fleet's
    tick): :class:`ReceiverState`'s fields with a leading row axis, one row per receiver.

    What a receiver's state leaves as None is a neutral value here: no start-up pending
    (``usable_from_t_unix_s`` -inf, ``no_fix_until_t_unix_s`` -inf), no start-up error
    (``has_start_bias`` False), no filter or held output (NaN rows), Gauss-Markov processes
    and tracking at their start (zeros, not tracked).
    :func:`~virtualgps.receiver.core.simulate` given rows computes each row as it computes one
    receiver's one epoch, to the bit.

    rngs : the receivers' own generators (the paper's two uniforms each)
    streams : the receivers' model streams (:func:`model_streams`)
    ahead : the uniforms drawn ahead (:meth:`uniforms`), shared by the rows that
        :func:`~virtualgps.receiver.core.simulate` returns
    """

    n_epochs: np.ndarray
    last_t_unix_s: np.ndarray
    no_fix_until_t_unix_s: np.ndarray
    gm_m: np.ndarray
    last_alt_hae_m: np.ndarray
    nav_enu_m: np.ndarray
    hold_enu_m: np.ndarray
    past_t_unix_s: np.ndarray
    past_enu_m: np.ndarray
    usable_from_t_unix_s: np.ndarray
    start_bias_enu_m: np.ndarray
    has_start_bias: np.ndarray
    fade_db: np.ndarray
    tracked: np.ndarray
    acq_run: np.ndarray
    mp_m: np.ndarray
    rr_mps: np.ndarray
    rngs: list
    streams: list
    ahead: _Ahead = field(default_factory=_Ahead, compare=False)

    def uniforms(self, plan: tuple[tuple[str, int, int], ...]) -> np.ndarray:
        """The next epoch's uniforms, (n, plan's last end column): each row what the receiver
        alone draws (:func:`draw_uniforms` for one epoch).

        Rows that go on together past their first epoch draw DRAW_AHEAD epochs at a time, one
        call per receiver and stream: a fleet's per-call costs were a tenth of its
        simulation. (Rows made afresh every epoch, as an overloaded fleet's chunks are, draw
        one at a time: what they drew ahead would only be given back.) A row taken out
        (:meth:`row_state`) first gives back what was drawn ahead of it (its generators are
        moved back), so whatever draws from them next draws what it would have.

        Parameters
        ----------
        plan : :func:`draw_plan` of the epoch's layout

        Returns
        -------
        u : (n, total) uniforms on [0, 1)
        """
        a = self.ahead
        if a.blocks and (a.plan != plan or a.used >= a.k or a.back.any()):
            self._give_back()
            a.blocks = []
        if not a.blocks:
            gens = [self._gens(name) for name, _, _ in plan]
            if a.epochs and a.rewinds is None:  # (looked at once: the generators stay)
                a.rewinds = all(hasattr(g.bit_generator, "advance") for gs in gens for g in gs)
            k = DRAW_AHEAD if a.epochs and a.rewinds else 1
            for (_, lo, hi), gs in zip(plan, gens, strict=True):
                block = np.empty((len(gs), k, hi - lo))
                for g, out in zip(gs, block, strict=True):
                    g.random(out=out)  # (k rows at once: the k rows drawn one by one)
                a.blocks.append(block)
            a.plan, a.used, a.k, a.back = plan, 0, k, np.zeros(len(self.rngs), bool)
        j = a.used
        a.used += 1
        a.epochs += 1
        return np.concatenate([b[:, j] for b in a.blocks], axis=1)

    def _gens(self, name: str) -> list[np.random.Generator]:
        return self.rngs if name == "usarsim" else [st[name] for st in self.streams]

    def _give_back(self, rows: list[int] | None = None) -> None:
        """Move the generators of ``rows`` (default: all not yet given back) back by what
        was drawn ahead of them and not used."""
        a = self.ahead
        if not a.blocks:
            return
        rows = [i for i in (range(len(a.back)) if rows is None else rows) if not a.back[i]]
        if a.used < a.k:
            # PCG64 steps back by advancing modulo its period, 2**128; one double is one step.
            for i in rows:
                for name, lo, hi in a.plan:
                    g = self.rngs[i] if name == "usarsim" else self.streams[i][name]
                    g.bit_generator.advance(-(a.k - a.used) * (hi - lo) % (1 << 128))
        a.back[rows] = True

    @staticmethod
    def stack(states: list[ReceiverState], rngs: list[np.random.Generator], profile: Profile,
              n_sat: int) -> ReceiverRows:
        """The rows of ``states`` (receivers with one ``profile`` and ``n_sat`` satellites).

        Parameters
        ----------
        states : one ReceiverState per receiver
        rngs : their generators
        profile : their profile (the width of the correlated-error state)
        n_sat : number of satellites

        Returns
        -------
        rows : ReceiverRows
        """
        ce = profile.correlated_error
        gm_w = n_sat if ce.domain == "range" else 3

        # latency's truth history, the last k known positions of each (NaN before them)
        k = history_len(profile)
        past_t, past_x = np.full((len(states), k), np.nan), np.full((len(states), k, 3), np.nan)
        for i, st in enumerate(states):
            if k and st.past_t_unix_s is not None:
                m = min(k, st.past_t_unix_s.size)
                past_t[i, k - m:] = st.past_t_unix_s[-m:]
                past_x[i, k - m:] = st.past_enu_m[-m:]

        def rows(name: str, width: int, fill, dtype=float) -> np.ndarray:
            out = np.full((len(states), width), fill, dtype)
            for i, st in enumerate(states):
                v = getattr(st, name)
                if v is not None and np.shape(v) == (width,):
                    out[i] = v
            return out

        return ReceiverRows(
            n_epochs=np.array([st.n_epochs for st in states]),
            last_t_unix_s=np.array([st.last_t_unix_s for st in states], float),
            no_fix_until_t_unix_s=np.array([st.no_fix_until_t_unix_s for st in states], float),
            gm_m=rows("gm_m", gm_w, 0.0),
            last_alt_hae_m=np.array([st.last_alt_hae_m for st in states], float),
            nav_enu_m=rows("nav_enu_m", 3, np.nan),
            hold_enu_m=rows("hold_enu_m", 3, np.nan),
            past_t_unix_s=past_t,
            past_enu_m=past_x,
            usable_from_t_unix_s=rows("usable_from_t_unix_s", n_sat, -np.inf),
            start_bias_enu_m=rows("start_bias_enu_m", 3, 0.0),
            has_start_bias=np.array([st.start_bias_enu_m is not None for st in states]),
            fade_db=rows("fade_db", n_sat, 0.0),
            tracked=rows("tracked", n_sat, False, bool),
            acq_run=rows("acq_run", n_sat, 0, int),
            mp_m=rows("mp_m", n_sat, 0.0),
            rr_mps=rows("rr_mps", n_sat, 0.0),
            rngs=list(rngs),
            streams=[st.streams if st.streams is not None else model_streams(r)
                     for st, r in zip(states, rngs, strict=True)],
        )

    def row_state(self, i: int, profile: Profile) -> ReceiverState:
        """Row ``i`` as a ReceiverState (None where the row holds the neutral value).

        Parameters
        ----------
        i : the row
        profile : the receivers' profile (which effects keep a state)

        Returns
        -------
        state : ReceiverState
        """
        self._give_back([i])
        ce, ct = profile.correlated_error, profile.cn0_tracking
        nav = self.nav_enu_m[i]
        hold = self.hold_enu_m[i]
        known = ~np.isnan(self.past_t_unix_s[i])
        usable = self.usable_from_t_unix_s[i]
        return ReceiverState(
            n_epochs=int(self.n_epochs[i]),
            last_t_unix_s=float(self.last_t_unix_s[i]),
            no_fix_until_t_unix_s=float(self.no_fix_until_t_unix_s[i]),
            gm_m=self.gm_m[i] if ce.enabled else None,
            last_alt_hae_m=float(self.last_alt_hae_m[i]),
            nav_enu_m=nav if not np.isnan(nav[0]) else None,
            hold_enu_m=hold if not np.isnan(hold[0]) else None,
            past_t_unix_s=self.past_t_unix_s[i][known] if known.any() else None,
            past_enu_m=self.past_enu_m[i][known] if known.any() else None,
            usable_from_t_unix_s=usable if usable.size and usable[0] != -np.inf else None,
            start_bias_enu_m=self.start_bias_enu_m[i] if self.has_start_bias[i] else None,
            fade_db=self.fade_db[i] if ct.enabled else None,
            tracked=self.tracked[i] if ct.enabled else None,
            acq_run=self.acq_run[i] if ct.enabled else None,
            mp_m=self.mp_m[i] if profile.multipath.enabled else None,
            rr_mps=self.rr_mps[i] if "velocity" in draw_layout(profile, 1) else None,
            streams=self.streams[i],
        )


def restart(
    state: ReceiverState,
    kind: str,
    t_unix_s: float,
    profile: Profile,
    rng: np.random.Generator,
    n_sat: int = 0,
) -> ReceiverState:
    """Restart the receiver: no fix until a time to first fix drawn for that kind of start.

    A cold start knows no almanac, ephemeris, time or position; warm keeps the almanac and time;
    hot keeps everything (MTK ``$PMTK103/102/101``; a full cold start, ``$PMTK104``, is a cold
    start here). TTFF ~ Normal(mean, ttff_sd_frac x mean), clipped at 0 (profile ``cold_start``).

    Parameters
    ----------
    state : the receiver state
    kind : "hot", "warm" or "cold"
    t_unix_s : when the restart happens, UTC seconds (simulated clock)
    profile : gives the TTFF parameters
    rng : random generator (one normal draw; with n_sat, n_sat uniforms and 3 normals more
        after a cold or warm start)
    n_sat : number of satellites: after a cold or warm start they become usable one by one
        after the TTFF, the four highest at once (0: all at the TTFF)

    Returns
    -------
    state : with ``no_fix_until_t_unix_s`` (and the start-up's per-satellite usable times and
        initial error) set
    """
    if kind not in START_KINDS:
        raise ValueError(f"start kind must be one of {START_KINDS}, not {kind!r}")
    cs = profile.cold_start
    mean_s = {"hot": cs.ttff_hot_s, "warm": cs.ttff_warm_s, "cold": cs.ttff_cold_s}[kind]
    ttff_s = max(0.0, mean_s * (1.0 + cs.ttff_sd_frac * float(rng.standard_normal())))
    t_fix = t_unix_s + ttff_s
    if kind == "hot" or n_sat == 0:  # the ephemerides are still valid: every satellite at once
        return replace(state, no_fix_until_t_unix_s=t_fix, usable_from_t_unix_s=None,
                       start_bias_enu_m=None)
    u = rng.random(n_sat)
    usable = t_fix + cs.decode_spread_s * u  # (the four strongest are usable at t_fix)
    bias = cs.converge_sigma_m * rng.standard_normal(3)
    return replace(state, no_fix_until_t_unix_s=t_fix, usable_from_t_unix_s=usable,
                   start_bias_enu_m=bias)


def initial_state(
    profile: Profile, t_unix_s: float, rng: np.random.Generator, n_sat: int = 0
) -> ReceiverState:
    """The state at power-on: a start of the profile's ``cold_start.power_on`` kind, if enabled.

    Parameters
    ----------
    profile : the receiver profile
    t_unix_s : power-on time, UTC seconds
    rng : random generator (drawn from when a start is made)
    n_sat : number of satellites (see :func:`restart`)

    Returns
    -------
    state : ReceiverState
    """
    state = ReceiverState()
    if profile.cold_start.enabled and profile.cold_start.power_on != "none":
        state = restart(state, profile.cold_start.power_on, t_unix_s, profile, rng, n_sat)
    return state


def running_state(profile: Profile, n_sat: int) -> ReceiverState:
    """The state of a receiver already running at its first epoch (a log that starts with a
    fix): every satellite at or above the acquisition threshold is tracked at once, instead of
    after ``reacq_s`` of signal as at power-on.

    Parameters
    ----------
    profile : the receiver profile; n_sat : number of satellites

    Returns
    -------
    state : ReceiverState
    """
    if not profile.cn0_tracking.enabled:
        return ReceiverState()
    # a run of epochs above the acquisition threshold longer than any reacquisition time
    return ReceiverState(acq_run=np.full(n_sat, 1 << 30, dtype=np.int64))


def draw_layout(profile: Profile, n_sat: int) -> dict[str, int]:
    """Columns of the per-epoch row of uniforms each error model uses.

    Parameters
    ----------
    profile : the receiver profile
    n_sat : number of satellites

    Returns
    -------
    layout : start columns ("usarsim", "white", "gm", "fade", "multipath", "velocity") and
        "total"; a
        model that is off takes none
    """
    # Box-Muller works in pairs: every block starts at an even column, so the normals of the
    # whole row (simulate makes them at once) are each block's own.
    even = n_sat + (n_sat % 2)
    cols = {"usarsim": 0}
    total = 2  # the paper's two uniforms, always drawn (keeps its bytes unchanged)
    if profile.dop_error.enabled:
        cols["white"] = total
        total += even
    ce = profile.correlated_error
    if ce.enabled:
        cols["gm"] = total
        total += even if ce.domain == "range" else 4
    if profile.cn0_tracking.enabled:
        cols["fade"] = total
        total += even
    if profile.multipath.enabled:
        cols["multipath"] = total
        total += even
    if profile.dop_error.enabled and profile.dop_error.range_rate_sigma_mps > 0:
        cols["velocity"] = total
        total += even
    cols["total"] = total
    return cols


# Each error model draws from a stream of its own, spawned from the run's generator by a fixed
# key, so switching one model on or off leaves every other model's numbers as they were:
# profiles that differ in one effect, run with the same seed, differ by that effect alone
# (common random numbers; the gap tool's fits compare exactly such profiles). One row of the
# run's own generator would reshuffle every column when a model's width joins the row.
_STREAM_KEYS = {"white": 1, "gm": 2, "fade": 3, "multipath": 4, "velocity": 5}
_STREAM_DOMAIN = 0x76677073  # "vgps": keeps these spawn keys apart from a caller's own


def model_streams(rng: np.random.Generator) -> dict[str, np.random.Generator]:
    """The error models' random streams for a run whose generator is ``rng``.

    They are children of ``rng``'s seed sequence (NumPy's ``SeedSequence`` spawning, by fixed
    keys: independent of the parent's stream and of one another, and not consuming it); a
    generator without a seed sequence seeds them from one draw of its own.

    Returns
    -------
    streams : {model name: numpy.random.Generator}
    """
    ss = getattr(rng.bit_generator, "seed_seq", None)
    if not isinstance(ss, np.random.SeedSequence):
        ss = np.random.SeedSequence(int(rng.integers(2**63)))
    key = tuple(ss.spawn_key) + (_STREAM_DOMAIN,)
    return {name: np.random.default_rng(np.random.SeedSequence(ss.entropy, spawn_key=key + (k,)))
            for name, k in _STREAM_KEYS.items()}


@functools.lru_cache(maxsize=32)
def draw_plan(layout_items: tuple[tuple[str, int], ...]) -> tuple[tuple[str, int, int], ...]:
    """The (model, first column, end column) blocks of a :func:`draw_layout`, in column order.

    Parameters
    ----------
    layout_items : ``tuple(layout.items())`` of a :func:`draw_layout` (hashable: cached)

    Returns
    -------
    plan : ((model, first column, end column), ...)
    """
    layout = dict(layout_items)
    starts = sorted((c, name) for name, c in layout.items() if name != "total")
    ends = [c for c, _ in starts[1:]] + [layout["total"]]
    return tuple((name, c, end) for (c, name), end in zip(starts, ends, strict=True))


def draw_uniforms(rng: np.random.Generator, streams: dict[str, np.random.Generator],
                  layout: dict[str, int], n_t: int) -> np.ndarray:
    """(n_t, layout["total"]) uniforms on [0, 1): the paper's two columns from ``rng``, each
    model's columns from its own stream (one row per epoch from each, so a batch draws what
    the same epochs drawn one at a time do)."""
    blocks = [(rng if name == "usarsim" else streams[name]).random((n_t, end - c))
              for name, c, end in draw_plan(tuple(layout.items()))]
    return blocks[0] if len(blocks) == 1 else np.concatenate(blocks, axis=1)
