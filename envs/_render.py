"""Shared matplotlib rendering for the environments: one figure, ``human`` or ``rgb_array``."""

from __future__ import annotations

import numpy as np

__all__ = ["FigureRenderer", "interactive_backend"]


def interactive_backend() -> bool:
    """Whether matplotlib's current backend can open a window."""
    import matplotlib

    backend = str(matplotlib.get_backend()).lower()
    try:
        from matplotlib.backends import BackendFilter, backend_registry

        names = backend_registry.list_builtin(BackendFilter.INTERACTIVE)
    except ImportError:  # pragma: no cover - matplotlib < 3.9
        from matplotlib import rcsetup

        names = rcsetup.interactive_bk
    return backend in {n.lower() for n in names}


class FigureRenderer:
    """A figure shown in a window (``"human"``; off-screen on headless machines) or
    rendered to an ``H × W × 3`` uint8 array (``"rgb_array"``).

    Subclasses create their axes on :attr:`fig`, update the artists, then call
    :meth:`present`.
    """

    def __init__(self, mode: str, fps: int, figsize: tuple[float, float], dpi: int) -> None:
        self.mode = mode
        self.fps = fps
        self.interactive = False
        if mode == "human":
            import matplotlib.pyplot as plt

            self._plt = plt
            self.interactive = interactive_backend()
            self.fig = plt.figure(figsize=figsize)
            if self.interactive:
                plt.ion()
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self.fig = Figure(figsize=figsize, dpi=dpi)
            FigureCanvasAgg(self.fig)

    def present(self) -> np.ndarray | None:
        """Draw the figure: show it (``human``) or return its pixels (``rgb_array``)."""
        self.fig.canvas.draw()
        if self.mode == "human":
            if self.interactive:
                self.fig.canvas.flush_events()
                self._plt.pause(1.0 / self.fps)
            return None
        buf = np.asarray(self.fig.canvas.buffer_rgba())
        return np.ascontiguousarray(buf[..., :3])

    def close(self) -> None:
        if self.mode == "human":
            self._plt.close(self.fig)
        self.fig = None
