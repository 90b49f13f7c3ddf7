"""PNG plots of trajectories (the paper's Section 5 figures)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.lines  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402



def time_unit(system) -> str:
    """What the time axis of a scenario's plots is in (the ``unit`` of the plot functions): ``system.time_unit``
    for a continuous model; for a sampled one (``system.sample``) the length of an event time (``1 min``); for a
    discrete model, nothing (an event time is a step).  A model in minutes once plotted as if in seconds."""
    if system.time == "continuous":
        return system.time_unit
    return f"{system.sample:g} {system.time_unit}" if system.sample is not None else ""


def _xlabel(time: str, unit: str = "") -> str:
    if time == "continuous":
        return "time t" + (f" ({unit})" if unit else "")
    return "event time tau" + (f" (one is {unit})" if unit else "")


# one style per kind of event (splitspec_core.simulation.metrics.Mark.kind)
MARK_STYLES = {
    "loss": dict(color="#c0392b", ls=":", lw=1.1),
    "rejoin": dict(color="#1e8449", ls="-.", lw=1.1),
    "switch": dict(color="#7f8c8d", ls="-", lw=0.6, alpha=0.5),
    "arc": dict(color="#7d3c98", ls="--", lw=1.0),
    "fault": dict(color="#d35400", ls="--", lw=1.0),
    "sensor": dict(color="#c2185b", ls=(0, (1, 2)), lw=1.2),
}
MARK_NAMES = {"loss": "agent lost", "rejoin": "agent rejoins (fresh estimate)", "switch": "graph switch",
              "arc": "arc dropped / restored", "fault": "scenario fault",
              "sensor": "sensor suspect / restored (bad data)"}
MAX_LABELLED_SWITCHES = 12  # beyond this, switches are ticks without text (the legend names them)
SWITCH_TICK = 0.07  # height of a switch tick at the top of the axes (axes fraction)
SWITCH_TICK_STYLE = dict(color="#34495e", ls="-", lw=1.6)
LABEL_BOX = dict(boxstyle="square,pad=0.05", facecolor="white", edgecolor="none", alpha=0.8)


def legend_outside(ax, **kw):
    """The legend to the right of ``ax``, outside the data (figures use constrained layout)."""
    return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8, **kw)


def _dense_switches(marks) -> bool:
    return sum(m.kind == "switch" for m in marks) > MAX_LABELLED_SWITCHES


def _labelled(marks) -> list:
    """The marks that get a text label: all but switches when there are too many of them."""
    return [m for m in marks if m.kind != "switch" or not _dense_switches(marks)]


def _draw_marks(ax, marks, *, text: bool) -> list:
    """Vertical lines at ``marks``; short labels at the bottom of ``ax`` when ``text``; legend proxies."""
    dense = _dense_switches(marks)
    for m in marks:
        if m.kind == "switch" and dense:  # a tick at the top per switch, not a line through the data
            ax.axvline(m.t, 1.0 - SWITCH_TICK, 1.0, **SWITCH_TICK_STYLE, gid="mark:switch")
        else:
            ax.axvline(m.t, **MARK_STYLES[m.kind], zorder=1.5, gid=f"mark:{m.kind}")
    for m in _labelled(marks) if text else ():
        ax.text(m.t, 0.02, " " + m.label, transform=ax.get_xaxis_transform(), rotation=90, va="bottom",
                ha="right", fontsize=7, color=MARK_STYLES[m.kind]["color"], gid=f"mark-label:{m.kind}",
                bbox=LABEL_BOX)  # readable over the line of an event close by (_spread_labels)
    kinds = [k for k in MARK_STYLES if any(m.kind == k for m in marks)]
    names = {**MARK_NAMES, "switch": "graph switch (ticks at the top)" if dense else MARK_NAMES["switch"]}
    style = {**MARK_STYLES, "switch": SWITCH_TICK_STYLE if dense else MARK_STYLES["switch"]}
    return [matplotlib.lines.Line2D([], [], **style[k], label=names[k]) for k in kinds]


def _spread(anchors, width: float, lo: float, hi: float) -> np.ndarray:
    """Positions for labels ``width`` wide, one per anchor: at least ``width`` apart, each cluster of labels that
    would overlap centred on its anchors' mean, within ``[lo, hi]`` (when they fit), in the anchors' order."""
    anchors = np.asarray(anchors, dtype=float)
    order = np.argsort(anchors, kind="stable")
    runs: list = []  # [first position, count, sum of anchors]
    for a in anchors[order]:
        runs.append([a, 1, a])
        while len(runs) > 1 and runs[-2][0] + runs[-2][1] * width > runs[-1][0]:  # overlaps the run before: merge
            n, total = runs[-2][1] + runs[-1][1], runs[-2][2] + runs[-1][2]
            runs[-2:] = [[total / n - (n - 1) * width / 2, n, total]]
    pos = np.concatenate([r[0] + width * np.arange(r[1]) for r in runs]) if runs else np.zeros(0)
    for k in range(pos.size):  # within the axes: forwards from lo, backwards from hi
        pos[k] = max(pos[k], lo if k == 0 else pos[k - 1] + width)
    for k in range(pos.size - 1, -1, -1):
        pos[k] = min(pos[k], hi if k == pos.size - 1 else pos[k + 1] - width)
    out = np.empty_like(pos)
    out[order] = pos
    return out


def _spread_labels(fig, ax) -> None:
    """Nudge the event labels of ``ax`` (texts with a ``mark-label`` gid) sideways so that no two overlap: events
    close in time got labels on top of one another.  Laid out once to know where the anchors fall; the nudges
    are offsets in points, so they hold at any dpi."""
    from matplotlib.transforms import offset_copy

    texts = [t for t in ax.texts if (t.get_gid() or "").startswith("mark-label")]
    if len(texts) < 2:
        return
    fig.draw_without_rendering()  # the constrained layout, then the labels' extents
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in texts]
    width = max(b.width for b in boxes) + 2.0  # rotated: the width is one line's height
    centres = [(b.x0 + b.x1) / 2 for b in boxes]
    box = ax.get_window_extent(renderer)
    new = _spread(centres, width, box.x0 + width / 2, box.x1 - width / 2)
    for t, c, x in zip(texts, centres, new):
        if abs(x - c) > 1e-6:
            t.set_transform(offset_copy(t.get_transform(), fig=fig, x=(x - c) * 72.0 / fig.dpi, units="points"))


def _envelope_label(time: str, rate: float, marks, pieces: int, *, across_switches: int = 0) -> str:
    law = f"exp(-{rate:g} t)" if time == "continuous" else f"{rate:g}^tau"
    why = [w for k, w in (("rejoin", "rejoin"), ("switch", "switch")) if any(m.kind == k for m in marks)]
    if across_switches:
        why = [w for w in why if w != "switch"]
        return (f"designed rate {law}\none constant across {across_switches} switches"
                + ("\nrestarted at each rejoin" if pieces > 1 else ""))
    if pieces <= 1:
        return f"designed rate {law}"
    return f"designed rate {law}\nfrom each restart ({', '.join(why) or 'restart'})"


def plot_errors(traj, path: Path, *, time: str, rate: float | None, title: str, marks=(), noise_free=None,
                adaptive: bool = False, unit: str = "") -> None:
    """Write :func:`errors_figure` to ``path`` (PNG)."""
    fig = errors_figure(traj, time=time, rate=rate, title=title, marks=marks, noise_free=noise_free,
                        adaptive=adaptive, unit=unit)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def errors_figure(traj, *, time: str, rate: float | None, title: str, marks=(), noise_free=None,
                  adaptive: bool = False, unit: str = ""):
    """Error norm per agent, log scale, events marked, with the designed envelope restarted at rejoins and switches.

    ``marks``: :func:`splitspec_core.simulation.metrics.event_marks` of the run.  The
    envelope ``c rate^(tau - tau_k)`` / ``c exp(-rate (t - t_k))`` starts afresh
    at every restart ``t_k`` (:func:`splitspec_core.simulation.metrics.envelope_restarts`)
    with the smallest constant above the noise-free errors of its piece.
    ``adaptive``: no envelope (thm. split_continuous_adaptive certifies no rate); ``rate`` None: no envelope either
    (directions no agent sees that do not decay, ``design.undetectable: exclude``).
    Lines carry ``gid`` ``envelope`` and ``mark:<kind>`` (tests find them there).
    Returns the figure (the caller closes it).
    """
    from splitspec_core.simulation.metrics import NO_CERTIFIED_RATE, envelope, envelope_restarts, max_error

    fig, ax = plt.subplots(figsize=(9.5, 4.4), layout="constrained")
    e = traj.errors()
    for k, aid in enumerate(traj.agent_ids):
        ax.semilogy(traj.t, e[:, k], lw=1.3, label=f"agent {aid}")
    ref = traj if noise_free is None else noise_free
    if noise_free is not None and noise_free is not traj:
        ax.semilogy(ref.t, max_error(ref), color="0.35", lw=1.0, ls=(0, (1, 1)), label="max error, noise-free run")
    if not adaptive and rate is not None:
        # Switches faster than the eye can follow leave pieces too short to show a rate (the fitted
        # envelope would trace the error itself): then one constant across them, restarted at rejoins only.
        across = sum(m.kind == "switch" for m in marks) if _dense_switches(marks) else 0
        restarts = envelope_restarts(ref.alive, np.zeros_like(ref.graph) if across else ref.graph)
        env = envelope(ref.t, max_error(ref), restarts, time=time, rate=rate, fit=True,
                       scale=np.linalg.norm(ref.x, axis=1))
        ax.semilogy(ref.t, env, "k--", lw=1.0, gid="envelope",
                    label=_envelope_label(time, rate, marks, restarts.size, across_switches=across))
    handles, _ = ax.get_legend_handles_labels()
    shown = e if ref is traj else np.concatenate([e.ravel(), max_error(ref)])  # the noise-free run in view too
    finite = shown[np.isfinite(shown) & (shown > 0)]
    if finite.size:
        lo, hi = np.log10(max(finite.min() * 0.5, 1e-16)), np.log10(finite.max() * 3)
        span = hi - lo
        if _labelled(marks):
            lo -= 0.22 * span  # a strip under the data for the marks' labels
        if _dense_switches(marks):
            hi += 0.09 * span  # a strip over the data for the switch ticks
        ax.set_ylim(10 ** lo, 10 ** hi)
    handles += _draw_marks(ax, marks, text=True)
    ax.set_xlabel(_xlabel(time, unit))
    ax.set_ylabel("|x_i - x|")
    ax.set_title(title + (f"\n{NO_CERTIFIED_RATE}" if adaptive else ""))
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax, handles=handles)
    _spread_labels(fig, ax)
    return fig


#: the most state components one states.png draws (run.show may pick more; run.rrd keeps every one)
MAX_ROWS = 16


def plot_states(traj, path: Path, *, time: str, title: str, marks=(), max_components: int = 8,
                reference=None, shown=None, unit: str = "") -> None:
    """Write :func:`states_figure` to ``path`` (PNG)."""
    fig = states_figure(traj, time=time, title=title, marks=marks, max_components=max_components, reference=reference,
                        shown=shown, unit=unit)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def states_figure(traj, *, time: str, title: str, marks=(), max_components: int = 8, reference=None, shown=None,
                  unit: str = ""):
    """Each state component: truth (black) versus every agent's estimate, events marked; without truth,
    ``reference`` (the centralized Kalman filter on the same measurements, (T, n)) in its place.  Each row is
    labelled with the state's name (``traj.states``: ``system.states``, else ``x1 .. xn``).  ``shown``: the
    components drawn (``run.show``: :attr:`~splitspec_core.scenarios.specs.Scenario.shown_states`), else the first
    ``max_components``.  Returns the figure (the caller closes it)."""
    # at most MAX_ROWS rows: a figure of more is a wall, and the recording has them all
    comps = list(shown)[:MAX_ROWS] if shown is not None else list(range(min(traj.x.shape[1], max_components)))
    n = len(comps)
    names = traj.states or tuple(f"x{c + 1}" for c in range(traj.x.shape[1]))
    fig, axes = plt.subplots(n, 1, figsize=(9.0, 1.6 * n + 0.8), sharex=True, squeeze=False, layout="constrained")
    extra = []
    for row, c in enumerate(comps):
        ax = axes[row, 0]
        for k, aid in enumerate(traj.agent_ids):
            ax.plot(traj.t, traj.xhat[:, k, c], lw=1.0, label=f"agent {aid}")
        if reference is None:
            ax.plot(traj.t, traj.x[:, c], "k", lw=2.0, alpha=0.6, label="truth")
        else:
            ax.plot(traj.t, reference[:, c], "k--", lw=1.6, alpha=0.7, label="centralized KF")
        extra = _draw_marks(ax, marks, text=False)
        ax.set_ylabel(names[c])
        ax.grid(True, alpha=0.3)
        big = traj.x[:, c] if reference is None else reference[:, c]
        early = np.nanmax(np.abs(big[: max(2, traj.t.size // 10)]))
        if early > 0 and np.nanmax(np.abs(big)) > 50 * early:  # a growing mode: keep the transient in view
            ax.set_yscale("symlog", linthresh=early)
            d0, d1 = math.ceil(math.log10(early)), math.floor(math.log10(np.nanmax(np.abs(big))))
            dec = [10.0 ** d for d in range(d0, d1 + 1, max(1, math.ceil((d1 - d0 + 1) / 3)))]
            ax.set_yticks([-v for v in dec[::-1]] + [0.0] + dec)  # a few decades each side, readable
            ax.minorticks_off()
            ax.set_ylabel(f"{names[c]} (symlog)")
    top = axes[0, 0]  # short labels above the first component
    for m in _labelled(marks):
        top.text(m.t, 1.02, m.label, transform=top.get_xaxis_transform(), rotation=90, va="bottom",
                 ha="center", fontsize=7, color=MARK_STYLES[m.kind]["color"], gid=f"mark-label:{m.kind}")
    fig.suptitle(title)
    handles, _ = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles=handles + extra, loc="outside right upper", fontsize=8)  # beside all rows, not one
    axes[-1, 0].set_xlabel(_xlabel(time, unit))
    _spread_labels(fig, top)
    return fig


def plot_monte_carlo(t, stats: dict, path: Path, *, time: str, title: str, marks=(), unit: str = "") -> None:
    """Mean RMS error over seeds with the 10-90 % band, events marked."""
    fig, ax = plt.subplots(figsize=(9.0, 4), layout="constrained")
    ax.fill_between(t, stats["p10"], stats["p90"], alpha=0.3, label="10-90 % of seeds")
    ax.semilogy(t, stats["mean"], lw=1.5, label=f"mean over {stats['seeds']} seeds")
    handles, _ = ax.get_legend_handles_labels()
    handles += _draw_marks(ax, marks, text=False)
    ax.set_xlabel(_xlabel(time, unit))
    ax.set_ylabel("RMS error over agents")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax, handles=handles)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_compare(res, errors_path: Path, ratios_path: Path, *, unit: str = "") -> None:
    """RMS error over time per estimator (mean over seeds) and the bar chart of ratios to the centralized KF, of a
    :class:`splitspec_core.CompareResult`."""
    t = res.t
    fig, ax = plt.subplots(figsize=(9.0, 4.2), layout="constrained")
    for name, c in res.curves.items():
        style = {"centralized KF": dict(color="k", lw=2.0), "KCF": dict(ls="--")}.get(name, {})
        ax.semilogy(t, c, label=name, **style)
    ax.set_xlabel(_xlabel(res.time, unit))
    ax.set_ylabel("RMS over agents of |x_i - x|")
    ax.set_title(f"{res.scenario}: mean over {len(res.seeds)} seeds")
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax)
    fig.savefig(errors_path, dpi=120)
    plt.close(fig)
    names = list(res.estimators)
    bars, missing, log = ratio_bars(res)
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    if log:
        ax.set_yscale("log")
    drawn = ax.bar([names.index(n) for n in bars], list(bars.values()),
                   color=["#888" if n == "centralized KF" else "C0" for n in bars])
    for b, r in zip(drawn, bars.values()):
        ax.text(b.get_x() + b.get_width() / 2, b.get_height(), f"{r:.3g}", ha="center", va="bottom", fontsize=8)
    for n, label in missing.items():  # no bar: a missing ratio is not 0
        ax.text(names.index(n), 0.03, label, transform=ax.get_xaxis_transform(), rotation=90, ha="center",
                va="bottom", fontsize=6, color="C3")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(range(len(names)), names, rotation=20, fontsize=8)
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.set_ylabel("steady RMS / centralized KF" + (" (log)" if log else ""))
    ax.set_title(f"{res.scenario}: estimation quality under noise")
    fig.tight_layout()
    fig.savefig(ratios_path, dpi=120)
    plt.close(fig)


def ratio_bars(res) -> tuple:
    """What the ratio chart of :func:`plot_compare` draws: ``(bars, missing, log)``, ``bars`` ``{name: ratio}`` of the
    rows with a ratio, ``missing`` ``{name: "n/a: reason"}`` (shortened to two lines) of the others, drawn as a label and
    no bar, and ``log`` True where the ratios span more than a decade."""
    bars = {n: r.ratio_to_centralized for n, r in res.estimators.items() if r.ratio_to_centralized is not None}
    missing = {n: textwrap.fill(textwrap.shorten(f"n/a: {r.ratio_note or 'no ratio'}", 110, placeholder=" ..."), 56)
               for n, r in res.estimators.items() if r.ratio_to_centralized is None}
    positive = [v for v in bars.values() if v > 0]
    log = bool(positive) and max(positive) > 10 * min(positive)
    return bars, missing, log


def plot_sweep(res: dict, path: Path) -> None:
    """RMS (predicted, simulated) and measured rate against q or g, certified values marked."""
    rows = [r for r in res["rows"] if "error" not in r]
    v = [r["value"] for r in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.6), layout="constrained")
    a1.plot(v, [r["predicted_rms"] for r in rows], "o-", label="predicted (Lyapunov)")
    a1.plot(v, [r["simulated_rms"] for r in rows], "x--", label="simulated")
    a1.set_yscale("log")
    a1.set_xlabel(res["parameter"])
    a1.set_ylabel("steady-state RMS error")
    a2.plot(v, [r["measured_rate"] if r["measured_rate"] is not None else np.nan for r in rows], "o-",
            label="measured (noise-free)")
    a2.axhline(res["rate"], color="k", ls="--", lw=0.8, label=f"{'target' if res.get('designed_note') else 'designed'} rate {res['rate']:g}")
    a2.set_xlabel(res["parameter"])
    a2.set_ylabel("decay rate" + (" (lam^tau)" if res["parameter"] == "q" else " (exp(-lam t))"))
    for ax in (a1, a2):
        for r in rows:
            if r["certified"]:
                ax.axvspan(r["value"] - 0.02, r["value"] + 0.02, color="green", alpha=0.15)
        if res["designed"] is not None:  # None: the adaptive gain, no designed g
            ax.axvline(res["designed"], color="C2", lw=1.0, label=f"designed {res['parameter']} = {res['designed']:g}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)  # below the data
    note = f"\nthe scenario's {res['designed_note']}" if res.get("designed_note") else ""
    fig.suptitle(f"{res['scenario']}: choosing {res['parameter']} (green: rate certified){note}")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_rate_sweep(res: dict, path: Path) -> None:
    """Steady RMS against the rate asked (``compare --sweep-rate``): the designs predicted (filled: rate certified,
    hollow: not), the centralized references, the KCF measured."""
    from splitspec_core.synthesis.kalman import SHIFTED_LABEL

    rows = res["rows"]
    x = [r["rate"] for r in rows]
    fig, ax = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    for key, label, color in (("whole", "whole state (design.consensus: whole)", "C0"),
                              ("split", "split (the paper's, riccati gains)", "C1")):
        y = [np.nan if r[key]["rms"] is None else r[key]["rms"] for r in rows]
        ax.plot(x, y, "-", color=color, label=label)
        for xi, yi, r in zip(x, y, rows):
            ax.plot(xi, yi, "o", color=color, mfc=color if r[key]["certified"] else "white")
    for key, label, style in (("kalman", "centralized Kalman filter", "k--"),
                              ("reference", SHIFTED_LABEL, "k:"),
                              ("kcf", "KCF (measured, no certificate)", "C2-.")):
        ax.plot(x, [np.nan if r[key] is None else r[key] for r in rows], style, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("rate asked" + (f" ({res.get('per_time', 'per second')})" if res["time"] == "continuous"
                                  else " (lam per event time)"))
    ax.set_ylabel("steady-state RMS error")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.suptitle(f"{res['scenario']}: what each rate costs in noise (filled: rate certified)")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_network_sweep(res: dict, path: Path) -> None:
    """Measured decay rate (and steady-state RMS when noisy) against loss or deadline, with the designed and the
    lossless rates; each seed a dot, the mean a line, levels certified under loss marked green."""
    rows = res["rows"]
    p = res["parameter"]
    scale, unit = (1000.0, "deadline (ms)") if p == "deadline" else (1.0, "loss probability per message")
    v = np.array([r["value"] for r in rows]) * scale
    panels = 2 if res["noisy"] else 1
    fig, axes = plt.subplots(1, panels, figsize=(5.6 * panels + 0.6, 4.6), layout="constrained", squeeze=False)
    a1 = axes[0, 0]
    for x, r in zip(v, rows):
        ys = [y for y in r["rates"] if y is not None]
        a1.plot([x] * len(ys), ys, ".", color="C0", alpha=0.35, ms=4)
    a1.plot(v, [np.nan if r["rate_mean"] is None else r["rate_mean"] for r in rows], "o-", color="C0",
            label=f"measured (noise-free, mean of {len(res['seeds'])} seeds)")
    a1.axhline(res["designed_rate"], color="k", ls="--", lw=0.9, label=f"designed rate {res['designed_rate']:g}")
    ll = res["lossless"]
    if ll["rate_mean"] is not None:
        a1.axhline(ll["rate_mean"], color="C2", ls=":", lw=1.2, label=f"lossless {ll['rate_mean']:.3g}")
    a1.set_ylabel("decay rate" + (" (lam^tau: smaller is faster)" if res["time"] == "discrete"
                                  else " (exp(-lam t): larger is faster)"))
    for x, r in zip(v, rows):
        a1.annotate(f"{100 * r['lost_fraction']:.0f}% lost", (x, 0), xycoords=("data", "axes fraction"),
                    xytext=(0, 3), textcoords="offset points", ha="center", fontsize=7, color="0.35")
    if res["noisy"]:
        a2 = axes[0, 1]
        a2.errorbar(v, [r["rms_mean"] for r in rows], yerr=[r["rms_std"] for r in rows], fmt="o-", color="C1",
                    capsize=3, label="steady-state RMS (mean +- sd over seeds)")
        a2.axhline(ll["rms_mean"], color="C2", ls=":", lw=1.2, label=f"lossless {ll['rms_mean']:.3g}")
        a2.set_ylabel("steady-state RMS error")
    for ax in axes[0]:
        for x, r in zip(v, rows):
            if r["certified"]:
                ax.axvspan(x - 0.01 * (v.max() - v.min() or 1), x + 0.01 * (v.max() - v.min() or 1),
                           color="green", alpha=0.2)
        ax.set_xlabel(unit)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    extra = "" if p == "loss" else f", delays {1000 * res['delay']['mean']:g} +- {1000 * res['delay']['jitter']:g} ms"
    certified = sum(r["certified"] for r in rows)
    fig.suptitle(f"{res['scenario']}: the design under {p}{extra}" + (f", q = {res['q']}" if res["q"] is not None else "")
                 + ("\n(green: certified under loss)" if certified else "\n(no level certified under loss: see "
                                                                       f"{p}_sweep.json)"), fontsize=11)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_reference(traj, ref: dict, path: Path, *, time: str, title: str, marks=(), unit: str = "") -> None:
    """Without truth, what can be known (:mod:`splitspec_core.studies.no_truth`): each agent's measurement residual,
    the consensus disagreement and each agent's distance to the centralized Kalman filter, log scale."""
    fig, axes = plt.subplots(3, 1, figsize=(9.5, 8.0), sharex=True, layout="constrained")
    panels = [("residual", "|y_i - C_i x_i|"), ("kf_distance", "|x_i - x_KF|")]
    for ax, (key, label) in zip((axes[0], axes[2]), panels):
        for k, aid in enumerate(traj.agent_ids):
            ax.semilogy(traj.t, ref[key][:, k], lw=1.1, label=f"agent {aid}")
        ax.set_ylabel(label)
    axes[1].semilogy(traj.t, ref["disagreement"], color="k", lw=1.3, label="max_ij |x_i - x_j|")
    axes[1].set_ylabel("disagreement")
    axes[0].set_title(title + "\nmeasurement residuals, consensus disagreement, distance to the centralized Kalman filter")
    extra = []
    for ax in axes:
        extra = _draw_marks(ax, marks, text=False)
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].set_xlabel(_xlabel(time, unit))
    handles, _ = axes[0].get_legend_handles_labels()
    fig.legend(handles=handles + [axes[1].get_lines()[0]] + extra, loc="outside right upper", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
