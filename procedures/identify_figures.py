"""The figures of `rig identify`: torques (Figures 5.2/5.3) and trajectories (Figure 5.1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def torques_figure(t, tau, preds: dict, path: Path, title: str) -> None:
    """Figure 5.2/5.3 style: (a) measured vs predicted torque per joint, (b) absolute errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    units = ("N m", "N m", "N")
    styles = {"ols": ("tab:orange", "--"), "wls": ("tab:green", ":"), "sdp": ("tab:red", "-")}
    for j in range(3):
        ax, ae = axes[j, 0], axes[j, 1]
        ax.plot(t, tau[:, j], color="k", lw=1.2, label="measured")
        for m, p in preds.items():
            c, ls = styles[m]
            ax.plot(t, p[:, j], color=c, ls=ls, lw=1.0, label=m.upper())
            ae.plot(t, np.abs(tau[:, j] - p[:, j]), color=c, ls=ls, lw=0.8, label=m.upper())
        ax.set_ylabel(f"joint {j + 1} [{units[j]}]")
        ae.set_ylabel(f"|error| [{units[j]}]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[0, 1].legend(loc="upper right", fontsize=8)
    axes[0, 0].set_title("(a) measured vs predicted")
    axes[0, 1].set_title("(b) absolute error")
    for ax in axes[2]:
        ax.set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trajectory_figure(t, q, dq, path: Path, title: str) -> None:
    """Figure 5.1 style: position and velocity of the three joints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for j, lab in enumerate(("q1 [rad]", "q2 [rad]", "q3 [m]")):
        axes[0].plot(t, q[:, j], label=lab)
        axes[1].plot(t, dq[:, j], label="d" + lab.replace("]", "/s]"))
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
