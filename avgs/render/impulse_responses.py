"""The impulse-response task's model as the renderer uses it (:class:`ImpulseResponseTaskModel`).

Trained on many source positions (``avgs train --task rir``), so the source is an input
(``source_aware``). A pose's filter is the predicted binaural response itself
(:class:`~avgs.acoustics.rir_model.RIRModel`: log magnitudes, and a waveform by
``RIRConfig.phase``); a render convolves the input with it (FFT; the synthesis settings do not
apply), a stream is a :class:`~avgs.acoustics.convolution.ConvolutionStream`, and a pose's
``gains`` are the response's long-term ear gains (:func:`~avgs.acoustics.rir_model.ear_transfer`).
With ``RIRConfig.direct_sound`` the direct sound is placed by geometry: nothing before distance /
c, the lagging ear the spherical head's ITD later (:func:`~avgs.acoustics.direct_placement.place_direct_sound`).
Continuous yaw: the network reads the facing through cos / sin of the yaw and of the direction
to the source; the yaw is taken modulo 360 first, so yaw 360 and yaw 0 give the same response
exactly, and between the four trained facings the network interpolates smoothly. A response
is kept within :data:`~avgs.render.tasks.HEADROOM_DB` as a binaural filter is.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.convolution import ConvolutionStream
from avgs.acoustics.impulse_response import convolve
from avgs.acoustics.rir_model import RIRModel, ear_transfer, response_waveform
from avgs.config import STFTConfig, SynthesisConfig
from avgs.data.frame import SceneFrame, signed_direction
from avgs.render.cells import early_frames, frame_interpolation, frame_nodes, listener_contexts
from avgs.render.tasks import HEADROOM_DB, BlockStream, HeadroomLimited, Pose, Response, check_finite, peak, reach_frames
from avgs.threads import stopped

RESPONSE_CHUNK = 32
"Poses per batch of :meth:`ImpulseResponseTaskModel.predict_responses`."


class ImpulseResponseTaskModel:
    """:class:`~avgs.render.tasks.TaskModel` of an :class:`~avgs.acoustics.rir_model.RIRModel`."""

    source_aware = True

    def __init__(self, model: RIRModel, cache, stft: STFTConfig, where: str, source_context,
                 frame: SceneFrame, bounds: np.ndarray):
        self.model, self.cache, self.stft, self.where = model, cache, stft, where
        self.frame, self.bounds = frame, bounds  # what early_frames reads
        self.rir = model.rir
        self._source_context = source_context
        self._fast_frames: dict = {}  # FastMap -> (frames [n_t], interpolation [n_t, N])

    @staticmethod
    def _yaw(yaw_degrees, like: torch.Tensor) -> torch.Tensor:
        """Yaws (degrees, any shape) as the network reads them: radians of the yaw modulo 360, ``like``'s dtype and device."""
        return torch.as_tensor(np.radians(np.asarray(yaw_degrees, dtype=np.float64) % 360.0)).to(like.device, like.dtype)

    def response(self, pose: Pose, impulse: bool = True, stop=None) -> Response:
        """The predicted response (always: it is what the gains are read from) and its ear gains."""
        stopped(stop, "the pose's response")
        yaw = self._yaw([pose.yaw], pose.listener)  # [1]
        log_mag, lis_idx, src_idx = self.model.log_magnitudes(pose.listener, yaw, pose.source, self.cache,
                                                              self._source_context(pose.source), stop=stop)
        stopped(stop, "the pose's response")
        mag = self.model.magnitudes(log_mag.float()).cpu()  # [1, 2, F, N]
        rc = self.rir
        direct = self.model.direct_sound(pose.listener, yaw, pose.source)
        stopped(stop, "the pose's response")
        h = response_waveform(mag, rc.length, self.stft, rc.phase, rc.phase_iterations, direct=direct,
                              stop=stop)[0]  # [2, L]
        gains = ear_transfer(mag, self.stft).double()  # [1, 2, F]
        check_finite((h, gains), self.where, f"response at listener {tuple(pose.listener_world)}, yaw {pose.yaw!r}")
        peak_db = 10.0 * math.log10(max(float(gains.square().max()), 1e-300))
        if peak_db > HEADROOM_DB:
            c = 10.0 ** ((HEADROOM_DB - peak_db) / 20.0)
            warnings.warn(f"the response at this pose gains {peak_db:.1f} dB in its loudest bin; scaled to "
                          f"the {HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=4)
            h, gains = h * c, gains * c
        return Response(gains, lis_idx, src_idx[0], impulse=np.ascontiguousarray(h.numpy(), dtype=np.float32))

    def render(self, response: Response, x: np.ndarray, synthesis: SynthesisConfig, magnitudes: bool = False):
        y = convolve(torch.from_numpy(x), torch.from_numpy(response.impulse)).numpy()  # [2, T]
        top = peak(y)
        mags = None
        if magnitudes and math.isfinite(top):
            mags = dsp.magnitude(torch.from_numpy(y), self.stft).double().numpy()
        return y, mags, top

    def reach_frames(self, synthesis: SynthesisConfig, n_frames: int | None = None, decay=None) -> int:
        """:func:`~avgs.render.tasks.reach_frames`: no tail beyond the response itself unless ``decay`` says one."""
        return reach_frames(self.stft, synthesis, decay, n_frames)

    def stream(self, response: Response, synthesis: SynthesisConfig, block_frames: int | None = None) -> BlockStream:
        """The input convolved with the response, whatever the synthesis."""
        return ConvolutionStream(response.impulse)

    def beyond_filter(self, synthesis: SynthesisConfig) -> bool:
        return False  # the render is the convolution with the response, whatever the synthesis

    def move_stream(self, stream: BlockStream, response: Response) -> None:
        stream.set_pose(None, response.impulse)

    def cell_power(self, listener, theta, yaw, source, cached_source, bins=None, fast=None) -> np.ndarray:
        """Each ear's power ``[n, 2, f]``: the response's gains squared, with ``fast`` from a subset of
        the bins and frames (:class:`~avgs.render.cells.FastMap`)."""
        model, n = self.model, len(listener)
        yaw_rad = self._yaw(np.full(n, float(yaw)), listener)  # [n]
        if fast is None:
            log_mag = model.log_magnitudes(listener, yaw_rad, source, self.cache, cached_source)[0]  # [n, 2, F, N]
            return ear_transfer(model.magnitudes(log_mag.float()).cpu(), self.stft).double().numpy() ** 2
        b = model.binauralizer
        if fast not in self._fast_frames:
            frames = frame_nodes(b.n_frames, early_frames(self), fast.tail_frames)  # [n_t]
            self._fast_frames[fast] = (frames, frame_interpolation(frames, b.n_frames))  # [n_t, N]
        frames, interpolate = self._fast_frames[fast]
        context = None
        if model.field is not None:
            c_s = cached_source[0][None].expand(n, -1)  # [n, c]
            context = torch.cat([c_s, listener_contexts(model, self.cache, listener)], dim=-1)  # [n, 2c] = C_S (+) C_L
        src = source[None].expand(n, -1)  # [n, 3]
        theta_r = signed_direction(listener, yaw_rad, src)  # [n], as RIRModel.log_magnitudes
        log_mag = b(listener, src, theta_r, yaw_rad, context, self.cache.frequency, frames, bins,
                    walls=model.walls(listener, src))  # [n, 2, f, n_t]
        gains = ear_transfer(model.magnitudes(log_mag @ interpolate.to(log_mag)).float().cpu(), self.stft)  # [n, 2, f]
        return gains.double().numpy() ** 2

    def predict_responses(self, source, receiver, yaw) -> np.ndarray:
        """Predicted binaural responses ``[N, 2, L]`` float32 (channel 0 = left), batched; positions
        normalised, yaw degrees; no clamping and no headroom limit."""
        rc = self.rir
        out = np.empty((len(source), 2, rc.length), dtype=np.float32)
        like = self.model.points.X
        for i in range(0, len(source), RESPONSE_CHUNK):
            sl = slice(i, i + RESPONSE_CHUNK)
            rec, yaw_rad, src = (torch.from_numpy(receiver[sl]).to(like), self._yaw(yaw[sl], like),
                                 torch.from_numpy(source[sl]).to(like))
            log_mag, _, _ = self.model.log_magnitudes(rec, yaw_rad, src, self.cache)
            out[sl] = response_waveform(self.model.magnitudes(log_mag.float()).cpu(), rc.length, self.stft, rc.phase,
                                        rc.phase_iterations, direct=self.model.direct_sound(rec, yaw_rad, src)).numpy()
        check_finite((torch.from_numpy(out),), self.where, "responses")
        return out
