"""Shared matplotlib rendering for the environments: one figure, ``human`` or ``rgb_array``;
the render-mode check and the no-render-mode warning of every environment."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from vesselid.errors import VesselidError

__all__ = ["FigureRenderer", "HeavePlot", "check_render_mode", "interactive_backend",
           "warn_no_render_mode"]


def check_render_mode(render_mode: str | None, modes: list[str]) -> str | None:
    """``render_mode`` if it is ``None`` or one of ``modes``, else a domain error."""
    if render_mode is not None and render_mode not in modes:
        raise VesselidError(f"render_mode must be one of {modes} or None, got {render_mode!r}")
    return render_mode


def warn_no_render_mode(env_id: str) -> None:
    """gymnasium's warning for ``render()`` on an environment made without a render mode."""
    gym.logger.warn(f"render() called without a render_mode; e.g. gym.make({env_id!r}, "
                    "render_mode='rgb_array')")


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


class _HeaveFigure(FigureRenderer):
    """Velocity vs reference, thrust and current of the recent window."""

    def __init__(self, mode: str, sensor: bool, fps: int) -> None:
        super().__init__(mode, fps, (6.4, 4.8), 100)
        self.sensor = sensor
        ax_v, ax_t, ax_c = self.fig.subplots(3, 1, sharex=True)
        (self.l_w,) = ax_v.plot([], [], label="w_a (true)")
        (self.l_y,) = ax_v.plot([], [], ".", ms=2, label="y1 (measured)")
        (self.l_r,) = ax_v.plot([], [], "--", label="w_ref")
        ax_v.set_ylabel("heave velocity")
        ax_v.legend(loc="upper left", fontsize="small")
        (self.l_tau,) = ax_t.step([], [], where="post")
        ax_t.set_ylabel("thrust τ")
        (self.l_c,) = ax_c.plot([], [], label="w_c (true)")
        (self.l_y2,) = ax_c.plot([], [], ".", ms=2, label="y2 (meter)")
        ax_c.set_ylabel("current")
        ax_c.set_xlabel("step")
        if sensor:
            ax_c.legend(loc="upper left", fontsize="small")
        self.axes = (ax_v, ax_t, ax_c)
        self.fig.tight_layout()

    def draw(self, hist: np.ndarray, title: str = "") -> np.ndarray | None:
        """``hist`` columns: k, w_a, y1, ref, tau, w_c, y2."""
        k, wa, y1, ref, tau, wc, y2 = hist.T
        self.l_w.set_data(k, wa)
        self.l_y.set_data(k, y1)
        self.l_r.set_data(k, ref)
        self.l_tau.set_data(k, tau)
        self.l_c.set_data(k, wc)
        self.l_y2.set_data(k, y2 if self.sensor else np.full_like(y2, np.nan))
        for ax in self.axes:
            ax.relim()
            ax.autoscale_view()
        if k.size:
            self.axes[0].set_xlim(k[0], max(k[-1], k[0] + 1))
        self.axes[0].set_title(title, fontsize="small")
        return self.present()


class HeavePlot:
    """The heave environments' recent history (a ring buffer per sub-environment) and its
    figure (created at the first :meth:`frames`)."""

    def __init__(self, mode: str, sensor: bool, fps: int, window: int, n: int) -> None:
        self.mode, self.sensor, self.fps = mode, sensor, fps
        self.hist = np.full((int(window), 7, n), np.nan)
        self.length = 0
        self.figure: _HeaveFigure | None = None

    def clear(self) -> None:
        self.length = 0

    def record(self, t: float, w_a, y1, ref, w_c, y2, tau=None) -> None:
        """Append the readings at step ``t``; ``tau`` is the thrust applied to the
        previous row."""
        window = self.hist.shape[0]
        if tau is not None and self.length:
            self.hist[(self.length - 1) % window, 4] = tau
        h = self.hist[self.length % window]
        h[0], h[1], h[2], h[3], h[4], h[5], h[6] = t, w_a, y1, ref, np.nan, w_c, y2
        self.length += 1

    def frames(self, title: str) -> list[np.ndarray | None]:
        """One frame per sub-environment (``None`` in ``human`` mode)."""
        if self.figure is None:
            self.figure = _HeaveFigure(self.mode, self.sensor, self.fps)
        window = self.hist.shape[0]
        n = min(self.length, window)
        hist = self.hist[np.arange(self.length - n, self.length) % window]
        return [self.figure.draw(np.ascontiguousarray(hist[:, :, i]), f"{title} env {i}")
                for i in range(hist.shape[2])]

    def close(self) -> None:
        if self.figure is not None:
            self.figure.close()
            self.figure = None
