"""sim_node's outputs beside its topics: the recording (``record``) and the live 3-D view (``foxglove_port``,
``foxglove_host``), each with its lifecycle in one place: opened by a parameter transaction
(:class:`flagbot_sim.device.Output`: a value it cannot serve refuses the whole set), swapped in when the set
applies, closed at cleanup and at exit.
"""
from __future__ import annotations

import os
from typing import Callable

from ..device import Refused
from ..physics import Simulation
from ..values import one_line


def recording_error(recorder) -> str:
    """The recording's write error: '' while healthy (and without a recording); set once, kept until closed."""
    return (recorder.error or "") if recorder is not None else ""


class _Output:
    """One output in service at a time (``current``, or None): :meth:`swap` retires the old one, announces the
    new one in the log."""

    keys: tuple[str, ...] = ()

    def __init__(self, log: Callable[[str], None]):
        self.log = log
        self.current = None

    def swap(self, opened) -> None:
        """``opened`` (or None: off) goes into service; the previous one is retired."""
        old, self.current = self.current, opened
        if old is not None:
            self._retire(old)
        if opened is not None:
            self.log(self._started(opened))

    def _retire(self, old) -> None:
        raise NotImplementedError

    def _started(self, opened) -> str:
        raise NotImplementedError


class RecordingOutput(_Output):
    """The recording to ``record``: ``current`` (a Recorder on the node, or None) and whether any recording
    failed to write during the run (``failed``: sim_node then exits with 1)."""

    keys = ("record",)

    def __init__(self, node, log: Callable[[str], None]):
        super().__init__(log)
        self.node = node
        self.failed = False

    @property
    def path(self) -> str:
        return self.current.path if self.current is not None else ""

    def open(self, values: dict, sim: Simulation):
        """A recorder on ``values["record"]`` (None for '') with ``values`` (every parameter's value once the set
        applies) and ``sim``'s resolved scene (file + overrides + n_flagella) in the metadata, so the recording
        alone reproduces the run. Raises Refused with the reason if the file cannot be created or written."""
        path = values["record"]
        if not path:
            return None
        from ..bag import BagWriteError, RunMetadata
        from .recorder import Recorder
        params = dict(values, scene_overrides=list(values["scene_overrides"]))
        meta = RunMetadata(scene_toml=sim.scene.to_toml(), parameters=params)
        try:
            rec = Recorder(self.node, path, None, meta)
        except BagWriteError as exc:          # its message names the file and why
            raise Refused(str(exc)) from None
        except Exception as exc:  # noqa: BLE001 - a BagError or anything else: refused, with the reason
            raise Refused(f"cannot record to {path!r}: {exc}") from None
        err = recording_error(rec)
        if err:         # opened, but writing its header already failed (a full disk): a file it cannot write
            try:
                rec.close()
            except Exception:  # noqa: BLE001
                pass
            raise Refused(f"cannot record to {path!r}: {err}")
        return rec

    def discard(self, rec) -> None:
        """Close ``rec`` and remove its file: its set was refused."""
        path = getattr(rec, "path", None)
        try:
            rec.close()
        except Exception:  # noqa: BLE001
            pass
        if path:
            try:
                os.remove(path)
            except OSError:
                pass

    def _retire(self, old) -> None:
        self.log(self._close(old))              # its summary

    def _started(self, rec) -> str:
        return f"recording to {rec.path}"

    def close(self) -> str | None:
        """Close the current recording; its summary line (None if there was none)."""
        rec, self.current = self.current, None
        return self._close(rec) if rec is not None else None

    def check(self) -> str:
        """The current recording's write error ('' if none). The recorder logs it itself, once."""
        err = recording_error(self.current)
        if err:
            self.failed = True
        return err

    def _close(self, rec) -> str:
        """Close ``rec``; the summary line to report."""
        try:
            s = rec.close()
        except Exception as exc:  # noqa: BLE001 - a close that fails is reported, it must not kill the node
            self.failed = True
            return f"recording {getattr(rec, 'path', '?')} could not be closed: {type(exc).__name__}: {exc}"
        if s.error:
            self.failed = True
        return (f"recording closed: {s.path}, {s.messages} messages on {len(s.topics)} topics, "
                f"{s.duration:.1f} s, {s.size_bytes / 1024:.0f} KiB"
                + (f", {sum(s.lost.values())} messages lost before reaching it" if any(s.lost.values()) else "")
                + (f", ERROR {s.error}" if s.error else ""))


class ViewOutput(_Output):
    """The live view for the Foxglove app on ``foxglove_port`` (0: off) at ``foxglove_host``: ``current`` (a
    LiveView, or None)."""

    keys = ("foxglove_port", "foxglove_host")

    def __init__(self, log: Callable[[str], None], warn: Callable[[str], None]):
        super().__init__(log)
        self.warn = warn

    @property
    def url(self) -> str:
        return self.current.url if self.current is not None else ""

    def open(self, values: dict, sim: Simulation):
        """A live view on ``values["foxglove_port"]`` (None for 0); Refused with the reason if it cannot serve
        there."""
        if not values["foxglove_port"]:
            return None
        from ..optional import MissingExtra
        try:
            from ..view.live import LiveView, ViewError
            return LiveView(host=values["foxglove_host"], port=int(values["foxglove_port"]),
                            frame=values["frame_id"], child_frame=values["child_frame_id"], log=self.warn)
        except (MissingExtra, ViewError, ValueError, OSError) as exc:
            raise Refused(one_line(str(exc))) from None

    def discard(self, view) -> None:
        view.close(linger=0.0)

    def _retire(self, old) -> None:
        old.close(linger=0.0)

    def _started(self, view) -> str:
        return f"live view for the Foxglove app at {view.url}"

    def update(self, sim: Simulation, snapshot) -> None:
        if self.current is not None:
            self.current.update(sim, snapshot=snapshot)

    def close(self) -> None:
        if self.current is not None:
            self.current.close()
            self.current = None
