"""``cloth-lod run SCENE --foxglove [PORT]``: a headless run served live at real speed.

A person watching wants to see the motion as it happens, so the run:

1. starts the server before the simulator is built (the first start compiles
   kernels; a viewer can connect meanwhile) and says where to connect;
2. waits for a viewer to subscribe, so nothing is missed while the app opens;
3. paces the steps to the wall clock (a step is not taken before its
   simulated time has passed in real time; a run slower than real time is
   not slowed further) and sends a frame every ``1 / rate`` s of simulated time;
4. after the run (and its output files), keeps serving the final state until
   Ctrl-C, re-sent every second for viewers that connect late.
"""

from __future__ import annotations

import sys
import time

from .server import LiveView

__all__ = ["LiveRun", "RATE"]

RATE = 30.0                 # Hz of simulated (= wall, paced) time between frames
HOLD_PERIOD = 1.0           # s between re-sends of the final state
SETTLE = 0.5                # s from a viewer's first subscription to the first frame


class LiveRun:
    """The live side of one headless run.

    Args:
        host, port: where the server listens (port 0: any free port).
        frame_id: frame of the entities.
        out: stream for the messages to the user.
    """

    def __init__(self, host: str, port: int, frame_id: str = "world", out=None):
        self.out = out or sys.stdout
        self.view = LiveView(host, port, frame_id)
        self._say(self.view.instructions())
        self.sim = None

    def _say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def start(self, sim, callback):
        """Wait for a viewer, send the initial state, and return ``callback``
        wrapped to pace each step and send frames."""
        self.sim = sim
        if not self.view.has_viewers():
            self._say(f"waiting for a viewer to connect to {self.view.url} (Ctrl-C to stop)")
            while not self.view.has_viewers():
                time.sleep(0.05)
            # A viewer subscribes to its topics one message after another: let
            # them all arrive before the first frame.
            time.sleep(SETTLE)
            self._say("viewer connected: running in real time")
        self.view.publish(sim, force=True)
        wall0, sim0 = time.monotonic(), sim.time
        period = 1.0 / RATE
        next_frame = sim.time + period

        def paced(s, stats):
            nonlocal next_frame
            callback(s, stats)
            delay = wall0 + (s.time - sim0) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if s.time >= next_frame - 1e-9:
                self.view.publish(s, force=True)
                while next_frame <= s.time + 1e-9:
                    next_frame += period
        return paced

    def hold(self) -> None:
        """Serve the final state until Ctrl-C, then stop the server."""
        self._say(f"run finished at t = {self.sim.time:.3f} s; {self.view.url} keeps showing "
                  "the final state: Ctrl-C to stop")
        try:
            while True:
                self.view.publish(self.sim, force=True)
                time.sleep(HOLD_PERIOD)
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        self.view.close()
