"""One ``rgb2cloud stream``: every frame through one WebSocket, each answer written to every sink in a thread of
its own, and the tally of what became of the frames, however the stream ends."""

from __future__ import annotations

import itertools
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cli.stream_frames import Fitting, Sending, Unreadable, paced, stream_options
from contract.errors import UserError

if TYPE_CHECKING:
    from clients.sinks import Sink
    from clients.sinks.folder import FolderSink
    from clients.stream import Answer
    from recordings.sources import Source, SourceFrame


def run_stream(
    source: Source,
    url: str,
    sinks: list[Sink],
    given: dict[str, Any],
    given_camera: dict[str, float],
    max_pixels: int,
    tally: Tally,
    rate: float = 0.0,
    skip_written: FolderSink | None = None,
) -> None:
    """Every frame through one stream into every sink (``clients.sinks``); ``tally`` counts what became of the
    frames, also when the stream ends in an error. ``given_camera`` is the user's camera for a source whose
    frames carry none, in its frames' pixels; ``rate`` paces a recording (``paced``); ``skip_written`` leaves
    out frames a folder holds already. A photo the client cannot open is one line that names it, and the
    stream goes on with the next."""
    from tqdm import tqdm
    from websockets.exceptions import InvalidHandshake

    from clients.stream import answers, open_stream

    frames = source.frames
    if skip_written is not None and not source.live:
        frames = (f for f in frames if not all(p.exists() for p in skip_written.paths(f.name)))
    frames = paced(frames, 0.0 if source.live else rate)

    def say(line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    fitting = Fitting(max_pixels, given_camera, say)

    def readable(frames: Iterable[SourceFrame]) -> Iterator[Sending]:
        for frame in frames:
            fitted = fitting(frame)
            if isinstance(fitted, Unreadable):
                tally.unreadable += 1
                say(f"{fitted.name}: skipped, {fitted.why}")
            else:
                yield fitted

    sending = readable(frames)
    first = next(sending, None)
    if first is None:
        return
    sending = itertools.chain([first], sending)
    try:
        socket = open_stream(url, max_pixels=max_pixels, **stream_options(first, given))
    except InvalidHandshake as e:
        raise UserError(f"{url}: the service refused the stream: {e}") from None
    except (OSError, TimeoutError) as e:  # nothing listening, no route, a handshake that never came
        raise UserError(f"{url}: cannot open the stream: {e}") from None
    bar = tqdm(desc="stream", unit="frame", mininterval=1.0)
    started = time.perf_counter()
    writer = Writer(sinks)
    try:
        with socket:
            for answer in answers(socket, sending, lambda s: s.frame.data, source.live, options_of=lambda s: s.camera):
                bar.update(1)
                tally.sent_again += answer.tries > 1
                if answer.error is not None:
                    tally.refused += 1
                    say(f"{answer.item.frame.name}: {answer.error}")
                    continue
                writer.put(answer)
                rate = writer.written / max(1e-9, time.perf_counter() - started)
                bar.set_postfix(fps=f"{rate:.1f}", skipped=answer.header["skipped"], refresh=False)
    finally:  # the bar closed and every answer counted whatever ends the stream
        failure = writer.finish()
        bar.close()
        tally.written = writer.written
        rising = sys.exc_info()[1]
        if failure is not None and rising is None:
            raise failure
        if failure is not None and failure is not rising:  # the writer's own failure, re-raised by put, is said once
            say(f"also, an output failed: {failure}")  # the error on its way up is the one the user sees


@dataclass
class Tally:
    """What became of a stream's frames: written to every sink, refused by the service (its words said per
    frame), skipped as photos the client could not open (each named as it was), and sent again after a 503
    (the service was busy), whether or not they then came back."""

    written: int = 0
    refused: int = 0
    unreadable: int = 0
    sent_again: int = 0

    @property
    def skipped(self) -> int:
        return self.refused + self.unreadable

    def summary(self) -> str:
        said = [f"{self.written} frames written"]
        if self.refused:
            said.append(f"{self.refused} refused by the service")
        if self.unreadable:
            said.append(f"{self.unreadable} skipped as unreadable")
        if self.sent_again:
            said.append(f"{self.sent_again} sent again while the service was busy")
        return ", ".join(said)


class Writer:
    """Writes answers to the sinks in a thread of its own, in order, so the next answers are read (and the
    service kept busy) while a frame's files and messages go out. ``finish`` writes what is queued and stops;
    after Ctrl-C too, so each frame is written whole or not at all."""

    def __init__(self, sinks: list[Sink], depth: int = 8):
        self.sinks, self.written = sinks, 0
        self._queue: queue.Queue[Answer[Sending] | None] = queue.Queue(maxsize=depth)
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (answer := self._queue.get()) is not None:
            if self._failure is None:
                try:
                    from clients.sinks import decoded

                    frame = decoded(answer.item.frame, answer.header, answer.payloads)
                    for sink in self.sinks:
                        sink.write(frame)
                    self.written += 1
                except BaseException as e:  # a full disk: raised where answers are read
                    self._failure = e

    def put(self, answer: Answer[Sending]) -> None:
        if self._failure is not None:
            raise self._failure
        self._queue.put(answer)

    def finish(self) -> BaseException | None:
        """Writes what is queued and stops; the failure that stopped the writing, if any, for the caller to
        raise or, where an error is already on its way up, to report beside it."""
        self._queue.put(None)
        self._thread.join()
        return self._failure


def close_all(sinks: list[Sink], echo: Callable[[str], None]) -> None:
    """Closes every sink, each whatever the others do: one that fails to close (a full disk under the bag)
    never leaves the next open. The first failure is raised once all are closed, unless an error is already
    on its way up (called from a ``finally``): that one is what the user sees, and the failures to close
    are each echoed as a line of their own."""
    failures = []
    for sink in sinks:
        try:
            sink.close()
        except Exception as e:
            failures.append(e)
    in_flight = sys.exc_info()[1] is not None
    for failure in failures if in_flight else failures[1:]:
        echo(f"also, an output failed to close: {failure}")
    if failures and not in_flight:
        raise failures[0]
