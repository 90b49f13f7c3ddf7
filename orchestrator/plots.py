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
