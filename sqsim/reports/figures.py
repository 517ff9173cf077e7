"""Pieces shared by the reports' figures."""

from __future__ import annotations

__all__ = ["finish_topdown"]


def finish_topdown(fig, ax, path, dpi):
    """Axes, legend and file of a top-down (world x-y) figure; saves ``fig`` to ``path`` and closes it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    ax : matplotlib.axes.Axes
        Its plot, already drawn in metres of world x and y.
    path : str or os.PathLike
        PNG file.
    dpi : int
    """
    import matplotlib.pyplot as plt

    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
