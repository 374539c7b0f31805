"""What ``thinkfast-run status`` shows: daemons' status messages as a terminal view (rich).

Pure of I/O: :class:`StatusBoard` keeps each daemon's last status (by key prefix) with the
receive time and the EGM counters of the status before, for rates; :func:`render` draws the
board (one panel per daemon) and :func:`snapshot` gives it as plain data (``--json``). The
zenoh edge is :mod:`thinkfast.daemon.status_cli`. Keys are the status schema's
(docs/schemas/status.schema.json); a key a daemon does not send is shown as ``-``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

STALE_AFTER = 1.0  # s without a status: the panel says stale (the daemon sends 20 per second)
RATE_MIN_SPAN = 0.2  # s of status stamps before a rate is computed


@dataclass
class Seen:
    """One daemon as last heard: its status, when it came [s, receiver's clock], and the EGM
    counters and stamp of an earlier status (at least ``RATE_MIN_SPAN`` older) for rates."""

    status: dict
    received: float
    base: tuple[float, dict] | None = None
    rates: dict = field(default_factory=dict)


class StatusBoard:
    """The last status of every daemon heard, by key prefix."""

    def __init__(self):
        self.daemons: dict[str, Seen] = {}

    def update(self, prefix: str, status: dict, received: float) -> None:
        """Take ``status`` (a decoded status message) of the daemon at ``prefix``."""
        egm = status.get("egm") if isinstance(status.get("egm"), dict) else {}
        stamp = status.get("stamp")
        old = self.daemons.get(prefix)
        seen = Seen(status, received)
        if old is not None and isinstance(stamp, int | float):
            seen.base, seen.rates = old.base, old.rates
            if seen.base is None:
                seen.base = (stamp, egm)
            span = stamp - seen.base[0]
            if span >= RATE_MIN_SPAN:
                seen.rates = egm_rates(seen.base[1], egm, span)
                seen.base = (stamp, egm)
        elif isinstance(stamp, int | float):
            seen.base = (stamp, egm)
        self.daemons[prefix] = seen

    def age(self, prefix: str, now: float) -> float:
        """Seconds since the last status of ``prefix`` [s]."""
        return now - self.daemons[prefix].received


def egm_rates(before: dict, after: dict, span: float) -> dict:
    """Per second [1/s] of each EGM counter between two statuses ``span`` [s] apart."""
    return {
        k: round((after[k] - before.get(k, 0)) / span, 1)
        for k in after
        if isinstance(after[k], int) and isinstance(before.get(k, 0), int)
    }


def snapshot(board: StatusBoard, now: float) -> dict:
    """``{prefix: {"age_s", "stale", "egm_rates", "status"}}`` for every daemon heard."""
    return {
        p: {
            "age_s": round(board.age(p, now), 3),
            "stale": board.age(p, now) > STALE_AFTER or bool(s.status.get("exiting")),
            "egm_rates": s.rates,
            "status": s.status,
        }
        for p, s in sorted(board.daemons.items())
    }


def _text(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def _get(d: dict, *path, default=None):
    for name in path:
        if not isinstance(d, dict) or name not in d:
            return default
        d = d[name]
    return d


def panel_rows(status: dict, rates: dict, age: float) -> list[tuple[str, str]]:
    """(label, text) rows of one daemon's panel (the content :func:`render` draws)."""
    s, egm = status, status.get("egm") or {}
    state = _text(s.get("state"))
    if s.get("braking"):
        state += f" (braking: {_text(s.get('brake_reason'))})"
    if s.get("exiting"):
        state += " (exiting)"
    ctl = s.get("controller") or {}
    timing = s.get("egm_timing") or {}
    last = _get(s, "interventions", "last_throw")
    cams = s.get("cameras") or {}
    det = s.get("detections") or {}
    dropped = det.get("dropped") or {}
    robot = s.get("robot") if isinstance(s.get("robot"), dict) else {}
    rows = [
        ("state", state),
        (
            "cell",
            f"robot {_text(robot.get('name'))} ({_text(robot.get('robot_toml'))}), tree "
            f"{_text(s.get('tree_fingerprint'))}, plane x {_text(s.get('plane_x'))} m",
        ),
        (
            "planner",
            f"{_text(s.get('planner'))}, speed scale {_text(s.get('speed_scale'))}"
            + (", shadow" if s.get("shadow") is not None else ""),
        ),  # fmt: skip
        (
            "throws",
            f"{_text(s.get('throws'))}, node {_text(s.get('node'))}, "
            f"value {_text(s.get('value'))}, decision {_text(s.get('decision_ms'))} ms",
        ),
        (
            "controller",
            f"connected {_text(s.get('egm_connected'))} ({_text(s.get('egm_peer'))}), "
            f"motors {_text(ctl.get('motors_on'))}, MCI {_text(ctl.get('mci_running'))}, "
            f"RAPID {_text(ctl.get('rapid_running'))}, standby {_text(ctl.get('standby'))}",
        ),
        (
            "EGM",
            ", ".join(
                f"{k} {egm[k]}"
                for k in (
                    "received",
                    "replied",
                    "superseded",
                    "deferred",
                    "resyncs",
                    "repeated",
                    "foreign",
                    "malformed",
                )
                if k in egm
            )
            or "-",
        ),
        (
            "EGM rate",
            f"replied {_text(rates.get('replied'))}/s, "
            f"superseded {_text(rates.get('superseded'))}/s"
            if rates
            else "(measuring)",
        ),
        ("reply timing", _timing(timing)),
        (
            "supervisor",
            f"intervened {_text(_get(s, 'interventions', 'intervened'))} of "
            f"{_text(_get(s, 'interventions', 'ticks'))} ticks; last throw "
            + (
                f"{last.get('intervened')} of {last.get('ticks')}"
                if isinstance(last, dict)
                else "-"
            )
            + (f"; {s['safety']}" if s.get("safety") else ""),
        ),
        (
            "faults",
            f"{_text(_get(s, 'faults', 'count'))} (recent {_text(_get(s, 'faults', 'recent'))}"
            f", latched {_text(_get(s, 'faults', 'latched'))}), planner errors "
            f"{_text(s.get('planner_errors'))}",
        ),
        (
            "detections",
            ", ".join(
                f"{k} {v}" for k, v in det.items() if k != "dropped" and not isinstance(v, dict)
            )
            + (f"; dropped {dropped}" if dropped else "")
            or "-",
        ),
        (
            "cameras",
            "; ".join(
                f"{c}: " + ", ".join(f"{k} {v}" for k, v in d.items()) for c, d in cams.items()
            )
            or "-",
        ),  # fmt: skip
        (
            "home",
            "away" + (f", way home {_text(s.get('way_home'))}")
            if s.get("away_from_home")
            else "at home or moving",
        ),  # fmt: skip
        ("recorder", _text(_get(s, "recorder", "state"))),
        ("status age", f"{age:.2f} s" + (" STALE" if age > STALE_AFTER else "")),
    ]
    return rows


def _timing(t: dict) -> str:
    wait, work = t.get("wait_us"), t.get("work_us")
    if not isinstance(work, dict):
        return "-"
    w = f"wait p50 {wait['p50']} p99 {wait['p99']} us, " if isinstance(wait, dict) else ""
    return f"{w}work p50 {work['p50']} p99 {work['p99']} max {work['max_all']} us (n {t.get('n')})"


def render(board: StatusBoard, now: float, waiting_for: tuple[str, ...] = ()):
    """The board as a rich renderable: one panel per daemon (and a line per prefix not heard)."""
    from rich.console import Group
    from rich.panel import Panel
    from rich.table import Table

    parts = []
    for prefix, seen in sorted(board.daemons.items()):
        age = board.age(prefix, now)
        table = Table.grid(padding=(0, 2))
        table.add_column(style="bold")
        table.add_column()
        for label, text in panel_rows(seen.status, seen.rates, age):
            table.add_row(label, text)
        stale = age > STALE_AFTER or seen.status.get("exiting")
        style = "red" if stale or seen.status.get("state") == "fault" else "green"
        parts.append(Panel(table, title=f"{prefix}/status", border_style=style))
    for prefix in waiting_for:
        if prefix not in board.daemons:
            parts.append(f"{prefix}/status: no status heard yet")
    return Group(*parts)
