"""Many receivers in one daemon: ``virtualgps run --receivers N`` or ``--fleet FILE.toml``.

Each receiver has its own pseudo-terminal and link, command link, start-up state, seed and
random stream; all are simulated by one loop (:func:`virtualgps.run.daemon.run_receivers`), the
receivers due at an epoch in one sky computation, and their ptys served by one epoll loop
(:class:`~virtualgps.run.fleet.ptyloop.PtyLoop`).

- :mod:`~virtualgps.run.fleet.members` — who is in the fleet (``--receivers``, ``--fleet``).
- :mod:`~virtualgps.run.fleet.ptyloop` — the devices' writers, from one thread.
- :mod:`~virtualgps.run.fleet.run` — ``virtualgps run`` for a fleet.
"""
