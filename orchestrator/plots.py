"""PNG plots of trajectories (the paper's Section 5 figures)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402



def _xlabel(time: str) -> str:
    return "time t" if time == "continuous" else "event time tau"


def plot_errors(traj, path: Path, *, time: str, rate: float, c: float, title: str) -> None:
    """Error norm per agent, log scale, with the designed envelope ``c rate^tau`` / ``c exp(-rate t)``."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    e = traj.errors()
    for k, aid in enumerate(traj.agent_ids):
        ax.semilogy(traj.t, e[:, k], lw=1.3, label=f"agent {aid}")
    env = c * (np.exp(-rate * traj.t) if time == "continuous" else rate ** traj.t)
    lab = f"{c:.3g} exp(-{rate:g} t)" if time == "continuous" else f"{c:.3g} x {rate:g}^tau"
    ax.semilogy(traj.t, env, "k--", lw=1.0, label=f"designed envelope {lab}")
    died = np.nonzero(np.diff(traj.alive.astype(int), axis=0) < 0)
    for k_t, k_a in zip(*died):
        ax.axvline(traj.t[k_t + 1], color="red", lw=0.8, ls=":")
        ax.text(traj.t[k_t + 1], ax.get_ylim()[1], f" agent {traj.agent_ids[k_a]} lost", color="red",
                fontsize=7, va="top", rotation=90)
    finite = e[np.isfinite(e) & (e > 0)]
    if finite.size:
        ax.set_ylim(max(finite.min() * 0.5, 1e-16), finite.max() * 3)
    ax.set_xlabel(_xlabel(time))
    ax.set_ylabel("|x_i - x|")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_states(traj, path: Path, *, time: str, title: str, max_components: int = 8) -> None:
    """Each state component: truth (black) versus every agent's estimate."""
    n = min(traj.x.shape[1], max_components)
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.6 * n + 0.6), sharex=True, squeeze=False)
    for c in range(n):
        ax = axes[c, 0]
        for k, aid in enumerate(traj.agent_ids):
            ax.plot(traj.t, traj.xhat[:, k, c], lw=1.0, label=f"agent {aid}")
        ax.plot(traj.t, traj.x[:, c], "k", lw=2.0, alpha=0.6, label="truth")
        ax.set_ylabel(f"x{c + 1}")
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_title(title)
    axes[0, 0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1, 0].set_xlabel(_xlabel(time))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_monte_carlo(t, stats: dict, path: Path, *, time: str, title: str) -> None:
    """Mean RMS error over seeds with the 10-90 % band."""
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.fill_between(t, stats["p10"], stats["p90"], alpha=0.3, label="10-90 % of seeds")
    ax.semilogy(t, stats["mean"], lw=1.5, label=f"mean over {stats['seeds']} seeds")
    ax.set_xlabel(_xlabel(time))
    ax.set_ylabel("RMS error over agents")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_compare(res: dict, errors_path: Path, ratios_path: Path) -> None:
    """RMS error over time per estimator (mean over seeds) and the bar chart of ratios to the centralized KF."""
    curves = res["_curves"]
    t = curves["t"]
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for name, c in curves.items():
        if name == "t":
            continue
        style = {"centralized KF": dict(color="k", lw=2.0), "KCF": dict(ls="--")}.get(name, {})
        ax.semilogy(t, c, label=name, **style)
    ax.set_xlabel(_xlabel(res["time"]))
    ax.set_ylabel("RMS over agents of |x_i - x|")
    ax.set_title(f"{res['scenario']}: mean over {len(res['seeds'])} seeds")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(errors_path, dpi=120)
    plt.close(fig)
    names = list(res["estimators"])
    ratios = [res["estimators"][n]["ratio_to_centralized"] or 0.0 for n in names]
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    bars = ax.bar(range(len(names)), ratios, color=["#888" if n == "centralized KF" else "C0" for n in names])
    for b, r in zip(bars, ratios):
        ax.text(b.get_x() + b.get_width() / 2, b.get_height(), f"{r:.2f}", ha="center", va="bottom", fontsize=8)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(range(len(names)), names, rotation=20, fontsize=8)
    ax.set_ylabel("steady RMS / centralized KF")
    ax.set_title(f"{res['scenario']}: estimation quality under noise")
    fig.tight_layout()
    fig.savefig(ratios_path, dpi=120)
    plt.close(fig)


def plot_sweep(res: dict, path: Path) -> None:
    """RMS (predicted, simulated) and measured rate against q or g, certified values marked."""
    rows = [r for r in res["rows"] if "error" not in r]
    v = [r["value"] for r in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    a1.plot(v, [r["predicted_rms"] for r in rows], "o-", label="predicted (Lyapunov)")
    a1.plot(v, [r["simulated_rms"] for r in rows], "x--", label="simulated")
    a1.set_yscale("log")
    a1.set_xlabel(res["parameter"])
    a1.set_ylabel("steady-state RMS error")
    a2.plot(v, [r["measured_rate"] if r["measured_rate"] is not None else np.nan for r in rows], "o-",
            label="measured (noise-free)")
    a2.axhline(res["rate"], color="k", ls="--", lw=0.8, label=f"designed rate {res['rate']:g}")
    a2.set_xlabel(res["parameter"])
    a2.set_ylabel("decay rate" + (" (lam^tau)" if res["parameter"] == "q" else " (exp(-lam t))"))
    for ax in (a1, a2):
        for r in rows:
            if r["certified"]:
                ax.axvspan(r["value"] - 0.02, r["value"] + 0.02, color="green", alpha=0.15)
        ax.axvline(res["designed"], color="C2", lw=1.0, label=f"designed {res['parameter']} = {res['designed']:g}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{res['scenario']}: choosing {res['parameter']} (green: rate certified)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
