"""The render thread: changes coalesce, the newest wins, no queue of stale frames.

Requests never touch the pipeline: :meth:`RenderWorker.update` checks an update against the
target state (:meth:`.adapters.Adapter.check`) and merges it in; the thread wakes, takes the
whole target state as it is then (every update since the last frame at once), applies only its
difference from what the pipeline holds, and renders. While a drag sends ``preview`` updates the
frames are rendered at 1/``preview_scale`` of the size; once no update has come for ``settle``
seconds the same state is rendered at full size. A preview after a light, material or parameter
change also traces a reduced photon budget (:attr:`.adapters.Adapter.preview_divisors`; the
frame's ``reduced`` names it), the full-size frame the user's. A progressive adapter then keeps
refining until a change arrives. Brush strokes and resets are actions, applied in order, never
dropped.

Frames are 8-bit sRGB (Mitsuba's sRGB curve, as ``photonmap render`` writes PNGs), streamed as
JPEG (quality :data:`PREVIEW_QUALITY` for previews, :data:`QUALITY` at full size: ≈ 5 ms for
1024 × 768 where a PNG takes ≈ 100 ms); the lossless PNG of a frame is encoded when first asked
for (``GET /api/frame.png``).
"""

from __future__ import annotations

import copy
import io
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError, PhotonmapError
from .state import changes, shown

QUALITY, PREVIEW_QUALITY = 92, 80


@dataclass
class Frame:
    """One rendered image and how it was made."""

    seq: int  # frame number
    version: int  # the state version it shows (every update accepted before it)
    preview: bool
    pixels: np.ndarray  # uint8 (h, w, 3), sRGB
    data: bytes  # the streamed image (JPEG)
    ms: float  # wall time of applying the changes, rendering and encoding
    timings: dict[str, float] = field(default_factory=dict)  # ms per stage that ran
    recomputed: list[str] = field(default_factory=list)
    fps: float = 0.0  # frames finished per second over the last two seconds
    passes: int = 1  # progressive methods: passes averaged
    parts: dict[str, float] = field(default_factory=dict)  # apply, render, encode: ms each
    error: str | None = None  # why the changes before it were undone (the pipeline refused)
    reduced: dict = field(default_factory=dict)  # a preview's reduced photon budget
    _png: bytes | None = None

    @property
    def png(self) -> bytes:
        """The frame as a PNG (lossless), encoded once when first asked for."""
        if self._png is None:
            self._png = encode(self.pixels, "png")
        return self._png

    def meta(self) -> dict:
        h, w = self.pixels.shape[:2]
        return {
            "type": "frame", "seq": self.seq, "version": self.version, "preview": self.preview,
            "width": w, "height": h, "mime": "image/jpeg", "ms": round(self.ms, 2),
            "timings": {k: round(v, 2) for k, v in self.timings.items()},
            "recomputed": self.recomputed, "fps": round(self.fps, 2), "passes": self.passes,
            "reduced": self.reduced,
            **{f"{k}_ms": round(v, 2) for k, v in self.parts.items()},
            **({"error": self.error} if self.error else {}),
        }  # fmt: skip


def to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear RGB → 8-bit sRGB (clamped), as :func:`photonmap.core.image.write_image`."""
    bmp = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32),
                    pixel_format=mi.Bitmap.PixelFormat.RGB)  # fmt: skip
    bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    return np.array(bmp).reshape(image.shape[0], image.shape[1], 3)


def encode(pixels: np.ndarray, fmt: str, quality: int = QUALITY) -> bytes:
    """``pixels`` as a PNG (lossless, fast compression) or JPEG file."""
    from PIL import Image

    out = io.BytesIO()
    if fmt == "png":
        Image.fromarray(pixels).save(out, format="PNG", compress_level=1)
    else:
        Image.fromarray(pixels).save(out, format="JPEG", quality=quality)
    return out.getvalue()


class RenderWorker:
    """Owns the adapter's pipeline on one thread; see the module docstring."""

    def __init__(self, adapter, preview_scale: int = 4, settle: float = 0.25):
        self.adapter = adapter
        self.preview_scale = preview_scale
        self.settle = settle
        self.target = copy.deepcopy(adapter.state)
        self.version = 0
        self.frame: Frame | None = None
        self.error: str | None = None  # why the next frame undid a change (shown once, on it)
        self._failure: str | None = None  # why no frame came for version _error_version
        self._error_version = -1
        self._preview = False
        self._actions: list[Callable[[], None]] = []
        self._rendered = -1  # the version of the last frame
        self._last_preview = False
        self._last_time = 0.0
        self._refining = False
        self._stop = False
        self._done = deque(maxlen=32)
        self._listeners: list[Callable[[dict, Frame | None], None]] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="photonmap-render", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- requests (any thread)
    def update(self, update: dict) -> tuple[dict, int]:
        """Check ``update`` and merge it into the target state; returns (state, version).
        A :class:`ParameterError` leaves the state unchanged."""
        preview = update.get("preview", False) if isinstance(update, dict) else False
        if not isinstance(preview, bool):
            raise ParameterError(f"preview must be true or false, got {shown(preview)}")
        with self._cond:
            new = self.adapter.check(self.target, update)
            self.target = new
            self.version += 1
            self._preview = preview
            self._cond.notify_all()
            return copy.deepcopy(new), self.version

    def act(self, action: Callable[[], None]) -> int:
        """Queue an edit the render thread runs before its next frame (a brush stroke, a reset)."""
        with self._cond:
            self._actions.append(action)
            self.version += 1
            self._preview = False
            self._cond.notify_all()
            return self.version

    def wait_frame(self, version: int | None = None, timeout: float = 300.0) -> Frame:
        """The first full-size frame that shows ``version`` (default: every change made so far)."""
        with self._cond:
            version = self.version if version is None else version
            ok = self._cond.wait_for(
                lambda: self._stop or self._error_version >= version or (
                    self.frame is not None and self.frame.version >= version
                    and not self.frame.preview and not self._actions
                ),
                timeout,
            )  # fmt: skip
            if self._error_version >= version and self._failure is not None:
                raise PhotonmapError(self._failure)
            if not ok or self.frame is None:
                raise TimeoutError(f"no frame of version {version} within {timeout} s")
            return self.frame

    def target_state(self) -> dict:
        """A copy of the state every accepted update leads to."""
        with self._cond:
            return copy.deepcopy(self.target)

    def subscribe(self, listener: Callable[[dict, Frame | None], None]) -> None:
        """Call ``listener(message, frame)`` from the render thread for each frame and error."""
        with self._cond:
            self._listeners.append(listener)

    def unsubscribe(self, listener) -> None:
        with self._cond:
            self._listeners.remove(listener)

    def stop(self) -> bool:
        """Stop the render thread after its current frame; whether it has ended (it is given
        30 s)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout=30)
        return not self._thread.is_alive()

    # ---------------------------------------------------------------- the render thread
    def _next(self):
        """Wait for work; returns (state, version, preview, actions, refine) or None to stop."""
        with self._cond:
            while not self._stop:
                if self.version != self._rendered or self._actions:
                    actions, self._actions = self._actions, []
                    return copy.deepcopy(self.target), self.version, self._preview, actions, False
                if self._last_preview:
                    remaining = self._last_time + self.settle - time.monotonic()
                    if remaining <= 0:
                        return copy.deepcopy(self.target), self.version, False, [], False
                    self._cond.wait(remaining)
                elif self._refining:
                    return None, self.version, False, [], True
                else:
                    self._cond.wait()
            return None

    def _run(self) -> None:
        applied = copy.deepcopy(self.adapter.state)
        good = None  # the state of the last frame rendered: a failed change goes back to it
        seq = 0
        while (work := self._next()) is not None:
            snapshot, version, preview, actions, refine = work
            start = time.perf_counter()
            applied_at = start
            try:
                if refine:
                    image = self.adapter.refine()
                    self._refining = image is not None
                    if image is None:
                        continue
                else:
                    diff = changes(applied, snapshot)
                    if diff:
                        try:
                            self.adapter.apply(diff, snapshot)
                        finally:  # what the pipeline holds now, whatever failed
                            applied = copy.deepcopy(self.adapter.state)
                    for action in actions:
                        action()
                    applied_at = time.perf_counter()
                    image = self.adapter.render(self._size(preview), preview)
                    self._refining = self.adapter.progressive and not preview
            except Exception as exc:  # the thread lives on; the page shows the reason
                if not isinstance(exc, PhotonmapError | MemoryError):  # one line, no traceback
                    first = (str(exc).strip().splitlines() or [""])[0][:200]
                    print(f"photonmap view: a render failed: {type(exc).__name__}: {first}",
                          file=sys.stderr, flush=True)  # fmt: skip
                back = None
                if snapshot is not None:
                    back, applied = self._roll_back(snapshot, applied, good)
                self._fail(exc, snapshot, back, version)
                continue
            if not refine:
                good = copy.deepcopy(applied)
            rendered_at = time.perf_counter()
            pixels = to_srgb8(image)
            data = encode(pixels, "jpeg", PREVIEW_QUALITY if preview else QUALITY)
            end = time.perf_counter()
            parts = {"apply": applied_at - start, "render": rendered_at - applied_at,
                     "encode": end - rendered_at}  # fmt: skip
            now = time.monotonic()
            self._done.append(now)
            recent = [t for t in self._done if now - t <= 2.0]
            seq += 1
            frame = Frame(
                seq, version, preview, pixels, data,
                1e3 * (end - start), self.adapter.timings, self.adapter.recomputed,
                len(recent) / 2.0, self.adapter.passes,
                {k: 1e3 * v for k, v in parts.items()}, reduced=dict(self.adapter.reduced),
            )  # fmt: skip
            with self._cond:
                frame.error, self.error = self.error, None  # the failure this frame undid
                listeners = list(self._listeners)
            for listener in listeners:  # first: a frame wait_frame returns has reached them
                listener(frame.meta(), frame)
            with self._cond:
                self.frame = frame
                self._rendered = max(self._rendered, version)
                self._last_preview, self._last_time = preview, now
                self._cond.notify_all()

    def _roll_back(self, snapshot: dict, applied: dict, good: dict | None):
        """After the change to ``snapshot`` failed: give the pipeline ``good`` again (the state of
        the last frame; before the first frame, what the pipeline took). Returns ``(back,
        holds)``: the state to render next (None: nothing to undo, or undoing failed too) and
        the state the pipeline holds."""
        back = good if good is not None else applied
        if back == snapshot:
            return None, applied
        if applied != back:
            try:
                self.adapter.apply(changes(applied, back), back)
            except Exception:  # noqa: BLE001 - undoing failed: no frame, the reason is shown
                return None, copy.deepcopy(self.adapter.state)
        return back, copy.deepcopy(self.adapter.state)

    def _fail(self, exc: Exception, snapshot: dict | None, back: dict | None, version: int):
        """A change the checks let through failed in the pipeline. ``back``: the state the
        pipeline went back to; unless a newer update came meanwhile it becomes the target, and
        the next frame renders it carrying the reason (once: ``error``). None: no frame for this
        version (:meth:`wait_frame` raises the reason). The page is told either way."""
        message = str(exc) if isinstance(exc, PhotonmapError) else f"{type(exc).__name__}: {exc}"
        message = message if len(message) <= 300 else message[:299] + "…"
        with self._cond:
            if back is not None:
                if self.target == snapshot:  # no newer update: the state before the change
                    self.target = copy.deepcopy(back)
                    self.version += 1
                self.error = message
            else:
                self._rendered = max(self._rendered, version)
                self._last_preview = self._refining = False
                self._error_version = version
                self._failure = message
            listeners = list(self._listeners)
            self._cond.notify_all()
        for listener in listeners:
            listener({"type": "error", "message": message, "version": version}, None)

    def _size(self, preview: bool) -> tuple[int, int]:
        cam = self.adapter.state["camera"]
        if not preview:
            return cam["width"], cam["height"]
        s = self.preview_scale
        return max(8, cam["width"] // s), max(8, cam["height"] // s)
