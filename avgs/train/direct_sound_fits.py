"""Where the direct sound of a predicted response goes, fitted on G_a's points and the training responses: the
straight path's test (how many points along a pair's path put it behind a wall), the walls' first reflections
and, behind a wall, the first sound's direction, its lag after distance / c and the early ILD's factor, and the
walls' count of B's wall term (:class:`DirectSoundFits`, a part of
:class:`~avgs.train.impulse_responses.ImpulseResponseTraining`).

Training's start fits them on G_a as stage 1 left it; its end fits them again on the points stage 2 left
(:meth:`DirectSoundFits.refit_geometry`), and fits the early ILD's factor with B trained. Only the direct sound's
placement at inference reads them, except the walls' count, which B's wall term reads while it trains.
"""

from __future__ import annotations

import numpy as np
import torch

from avgs.acoustics.interaural import fit_local_scale, local_features
from avgs.acoustics.rir_model import RIRModel
from avgs.data.frame import signed_direction


def local_table(train, theta: torch.Tensor, ilds: np.ndarray, in_sight: np.ndarray, predicted) -> tuple:
    """The ILD law's local correction (:func:`avgs.acoustics.interaural.local_correction`) from the training
    pairs ``train`` (normalised positions) in sight of the source, at directions ``theta [M]``, with early
    ILDs ``ilds [M]`` dB against what the model gives them, ``predicted [M]`` dB (the law, or the law with the
    walls' reflections): ``(local_at [m, 6], local_residual [m], local_scale [6])`` float32, the pairs whose
    ILD is finite."""
    keep = np.asarray(in_sight, dtype=bool) & np.isfinite(ilds)
    listener = torch.as_tensor(np.asarray(train.receiver, dtype=np.float64)[keep])
    source = torch.as_tensor(np.asarray(train.source, dtype=np.float64)[keep])
    th = theta[torch.as_tensor(keep)].double()
    residual = torch.as_tensor(ilds[keep], dtype=torch.float64) - torch.as_tensor(np.asarray(predicted, dtype=np.float64)[keep])
    where = local_features(listener, source, th)  # [m, 6]
    scale = fit_local_scale(where)
    return (where / scale).float(), residual.float(), scale.float()


class DirectSoundFits:
    """The fits of the direct sound's placement; the training task holds what they read: ``scene``, ``train_set``,
    ``responses``, the training pairs' ``_in_sight`` [M], ``_theta`` [M], ``_ilds`` [M], ``_itds`` [M] and
    ``_onsets`` [M], ``ild_law`` / ``ild_table`` and, before the walls' fit, ``_before_walls``, ``_seed``, ``_cfg``
    and the log (``_log``)."""

    def _fit_sight(self, model: RIRModel) -> None:
        """The straight path's test (:mod:`avgs.acoustics.line_of_sight`): the count of G_a's points along
        a training pair's path from which it is behind a wall, fitted to the pairs' own first arrivals."""
        from avgs.acoustics.line_of_sight import MARGIN_M, RADIUS_M, fit_blocked_count
        from avgs.acoustics.rir_binauralizer import NEVER_BLOCKED

        b, scale = model.binauralizer, float(self.scene.frame.scale)
        radius, margin = RADIUS_M * scale, MARGIN_M * scale  # the model's units
        counts = self._counts_on_paths(model, radius, margin)
        threshold = fit_blocked_count(counts, self._in_sight)
        with torch.no_grad():
            b.sight_radius.fill_(radius)
            b.sight_margin.fill_(margin)
            b.sight_blocked.fill_(NEVER_BLOCKED if threshold is None else threshold)
        if self._log is not None:
            sight = self._in_sight
            blocked = counts >= (NEVER_BLOCKED if threshold is None else threshold)
            self._log.write({"stage": "sight", "event": "fit", "blocked_from_points": threshold, "pairs_in_sight": int(sight.sum()),
                             "pairs_behind": int((~sight).sum()), "agree_in_sight": int((~blocked & sight).sum()),
                             "agree_behind": int((blocked & ~sight).sum())})

    def fit_reflections(self, model: RIRModel) -> None:
        """The walls' first-order reflections in the first 5 ms (``RIRConfig.early_reflections``,
        :mod:`avgs.acoustics.early_reflections`): the walls found in G_a's points, and the ILD law with the walls'
        gain fitted together to the training pairs in sight of the source, into ``model``'s buffers (its
        local correction's residuals then taken against them). No wall, or no fit: the law alone, as it was.
        After the straight path's test (:meth:`_fit_sight`), which the reflections' legs share."""
        from avgs.acoustics import early_reflections as er

        b, scale, train = model.binauralizer, float(self.scene.frame.scale), self.train_set
        points = model.points.X.detach().double().cpu()
        walls = er.find_walls(points, scale, seed=self._seed)  # [P, 3]
        test = er.ReflectionTest.at_scale(scale, b.sight_radius, b.sight_margin, b.sight_blocked)
        listener = torch.as_tensor(np.asarray(train.receiver), dtype=torch.float64)
        source = torch.as_tensor(np.asarray(train.source), dtype=torch.float64)
        yaw = torch.as_tensor(np.radians(np.asarray(train.yaw, dtype=np.float64)))
        distance = torch.linalg.vector_norm(source - listener, dim=-1)  # [M]
        found = er.wall_reflections(listener, source, walls, points, test, longest=distance + er.WINDOW_S * model.rir.sound_speed)
        P = walls.shape[0]
        reflected = er.image_directions(listener, yaw, found.image)  # [M, P]
        sight = torch.as_tensor(self._in_sight)
        fit = er.fit_early_ild(self._theta[sight], distance[sight], reflected[sight], found.path[sight], found.happens[sight],
                               self._ilds[self._in_sight], b.ild_law.detach().double().cpu().numpy()) if P else None
        record = {"stage": "reflections", "event": "fit", "walls": P, "pairs_in_sight": int(sight.sum()),
                  "reflections_per_pair": float(found.happens[sight].double().sum(-1).mean()) if P else 0.0}
        if fit is not None:
            law, gain = fit
            with torch.no_grad():
                b.reflecting_walls.zero_()
                b.reflecting_walls[:P].copy_(walls[: b.reflecting_walls.shape[0]])
                b.reflection_gain.fill_(gain)
                b.reflection_radius.fill_(test.surface_radius)
                b.reflection_points.fill_(float(test.surface_points))
                b.reflection_band.fill_(test.wall_band)
                b.ild_law.copy_(torch.as_tensor(law))
            self.ild_law = [float(c) for c in law]
            predicted = er.early_ild(self._theta, distance, reflected, found.path, found.happens, torch.as_tensor(law), gain)
            residual = (torch.as_tensor(self._ilds) - predicted)[sight]
            record.update({"gain": gain, "harmonics_db": self.ild_law, "median_abs_residual_db": float(residual.abs().nanmedian())})
            if getattr(b, "local_at", None) is not None:  # the local correction: what the walls leave
                self.ild_table = local_table(train, self._theta, self._ilds, self._in_sight, predicted.numpy())
                with torch.no_grad():
                    b.local_residual.copy_(self.ild_table[1])
        if self._log is not None:
            self._log.write(record)
        if fit is not None and getattr(b, "reflected_arrival", None) is not None:
            self._fit_arrival(model)

    def _fit_arrival(self, model: RIRModel) -> None:
        """Where the first sound behind a wall comes from (``RIRConfig.reflected_arrival``): on the training pairs
        whose straight path the points' test puts behind a wall and that have a first-order reflection off the
        walls found, the head's ITD at the reflection's direction against the straight direction's, and its
        path / c against distance / c, each against the pairs' measured early ITDs and onsets; each of the
        reflection's where it is the closer (:func:`~avgs.acoustics.early_reflections.reflection_first`), into
        ``model``'s ``reflected_arrival`` (direction, delay). Many pairs the points block hear their first sound
        within 1 ms of distance / c all the same (a third of three_rooms'): there the straight line's delay is
        the better one, and the onsets say so."""
        from avgs.acoustics.early_reflections import first_reflection, image_directions, reflection_first

        b = model.binauralizer
        at, listener, source, yaw = self._behind_a_wall(model)
        setup = model.reflection_setup()
        record = {"stage": "arrival", "event": "fit", "pairs_behind": int(at.numel()), "with_reflection": 0,
                  "direction": False, "delay": False}
        if setup is not None and at.numel():
            walls, test, _ = setup
            first = first_reflection(listener, source, walls, model.points.X.detach().double().cpu(), test)
            ok = first.found
            measured = -torch.as_tensor(self._itds, dtype=torch.float64)[at][ok]  # the head's sign: > 0 right ear later
            straight = model.head_itd(signed_direction(listener, yaw, source))[ok]
            reflected = model.head_itd(image_directions(listener, yaw, first.image[:, None])[:, 0])[ok]
            direction, itd_straight, itd_reflected = reflection_first(measured, straight, reflected)
            c = float(model.rir.sound_speed)
            onsets = torch.as_tensor(self._onsets, dtype=torch.float64)[at][ok]
            delay, onset_straight, onset_reflected = reflection_first(
                onsets, torch.linalg.vector_norm(source - listener, dim=-1)[ok] / c, first.path[ok] / c)
            record.update({"with_reflection": int(ok.sum()), "direction": direction, "delay": delay,
                           "itd_error_us": [None if e is None else 1e6 * e for e in (itd_straight, itd_reflected)],
                           "onset_error_ms": [None if e is None else 1e3 * e for e in (onset_straight, onset_reflected)]})
        with torch.no_grad():
            b.reflected_arrival.copy_(torch.tensor([float(record["direction"]), float(record["delay"])]))
        if self._log is not None:
            self._log.write(record)

    def fit_lag(self, model: RIRModel) -> None:
        """When the first sound behind a wall arrives (``RIRConfig.blocked_lag``): on the training pairs whose
        straight path the points' test puts behind a wall, the median of their onsets after distance / c (at
        least 0), into ``model``'s ``blocked_lag`` where distance / c plus it is closer to their onsets, by the
        median absolute error, than what the model places there without it (the straight line, or the first
        reflection: :meth:`_fit_arrival`); else 0. Needs :data:`~avgs.acoustics.early_reflections.ARRIVAL_PAIRS`
        pairs behind a wall. After the straight path's test and the first reflection's fit."""
        from avgs.acoustics.early_reflections import ARRIVAL_PAIRS

        b = model.binauralizer
        with torch.no_grad():
            b.blocked_lag.zero_()
        at, listener, source, yaw = self._behind_a_wall(model)
        record = {"stage": "lag", "event": "fit", "pairs_behind": int(at.numel()), "lag_ms": 0.0}
        if at.numel() >= ARRIVAL_PAIRS:
            c = float(model.rir.sound_speed)
            straight = torch.linalg.vector_norm(source - listener, dim=-1).numpy() / c  # [A] s
            onsets = np.asarray(self._onsets, dtype=np.float64)[at.numpy()]
            lag = max(0.0, float(np.median(onsets - straight)))
            with torch.no_grad():
                placed = model.direct_sound(listener.to(model.points.X), yaw.to(model.points.X), source.to(model.points.X))
            now = float(np.median(np.abs(placed.arrival.double().cpu().numpy() - onsets)))
            lagged = float(np.median(np.abs(straight + lag - onsets)))
            record.update({"onset_error_ms": [1e3 * now, 1e3 * lagged]})
            if lagged < now:
                record["lag_ms"] = 1e3 * lag
                with torch.no_grad():
                    b.blocked_lag.fill_(lag)
        if self._log is not None:
            self._log.write(record)

    def fit_blocked_ild(self, model: RIRModel) -> None:
        """Behind a wall, B's early ILD times a factor (``RIRConfig.blocked_ild``,
        :func:`avgs.train.blocked_ild.fit_factor`) fitted on the training pairs whose straight path the points'
        test puts behind a wall; 1 (B's own) with fewer than
        :data:`~avgs.acoustics.early_reflections.ARRIVAL_PAIRS` of them. With B trained: at the end."""
        from avgs.acoustics.early_reflections import ARRIVAL_PAIRS
        from avgs.train.blocked_ild import fit_factor

        with torch.no_grad():
            model.binauralizer.blocked_ild.fill_(1.0)
        at, listener, source, yaw = self._behind_a_wall(model)
        record = {"stage": "blocked_ild", "event": "fit", "pairs_behind": int(at.numel()), "factor": 1.0}
        if at.numel() >= ARRIVAL_PAIRS and self._ilds is not None:
            truth = np.asarray(self._ilds, dtype=np.float64)[at.numpy()]
            record.update(fit_factor(model, listener, yaw, source, truth, self._cfg.rir, self._cfg.stft, self.responses.length))
        if self._log is not None:
            self._log.write(record)

    def refit_geometry(self, model: RIRModel) -> None:
        """The straight path's test, the walls' reflections (with the first sound's direction behind a wall) and
        the lag behind a wall fitted again on G_a's points as they are now, at training's end: AV-GS's stage 2 adds
        and moves points, so a path that the start's count put in sight can end up behind a wall (three_rooms:
        19,997 points became 21,221, and of its 139 training pairs in sight 3 counted as behind a wall at the
        start, 7 to 11 at the end, three seeds). Only the placement of the direct sound reads these, so B's
        training is unchanged. The refit starts from the ILD law as it was before the walls' fit, and a fit that
        finds no walls now leaves none; on points that did not change it gives what the start gave."""
        b = model.binauralizer
        if self._in_sight is None or getattr(b, "ild_law", None) is None or self._before_walls[0] is None:
            return
        self._fit_sight(model)
        if getattr(b, "reflecting_walls", None) is not None:
            law, table = self._before_walls
            self.ild_law, self.ild_table = law, table
            with torch.no_grad():
                b.ild_law.copy_(torch.as_tensor(law, dtype=b.ild_law.dtype))
                b.reflecting_walls.zero_()
                b.reflection_gain.zero_()
                if getattr(b, "reflected_arrival", None) is not None:
                    b.reflected_arrival.zero_()
                if table is not None and getattr(b, "local_residual", None) is not None:
                    b.local_residual.copy_(table[1])
            self.fit_reflections(model)
        if getattr(b, "blocked_lag", None) is not None:
            self.fit_lag(model)
        if self._log is not None:
            self._log.write({"stage": "geometry", "event": "refit", "points": int(model.points.num_points)})

    def _behind_a_wall(self, model: RIRModel) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The training pairs whose straight path the points' test puts behind a wall (the deployment's test):
        their indices ``[A]``, listeners and sources ``[A, 3]`` (float64, model units) and yaws ``[A]`` radians."""
        b, train = model.binauralizer, self.train_set
        blocked = torch.as_tensor(self._counts_on_paths(model, float(b.sight_radius), float(b.sight_margin))
                                  >= float(b.sight_blocked))  # [M]
        at = torch.nonzero(blocked, as_tuple=True)[0]
        listener = torch.as_tensor(np.asarray(train.receiver), dtype=torch.float64)[at]
        source = torch.as_tensor(np.asarray(train.source), dtype=torch.float64)[at]
        yaw = torch.as_tensor(np.radians(np.asarray(train.yaw, dtype=np.float64)))[at]
        return at, listener, source, yaw

    def _counts_on_paths(self, model: RIRModel, radius: float, margin: float) -> np.ndarray:
        """How many of G_a's points lie along each training pair's straight path ``[M]`` (model units)."""
        from avgs.acoustics.line_of_sight import points_on_path

        train = self.train_set
        return points_on_path(model.points.X.detach().double().cpu(), torch.as_tensor(np.asarray(train.receiver), dtype=torch.float64),
                              torch.as_tensor(np.asarray(train.source), dtype=torch.float64), radius, margin).numpy()

    def _fit_walls(self, model: RIRModel) -> None:
        """The walls' count of B's wall term (``RIRConfig.wall_loss``): the straight path's test
        (:meth:`_fit_sight`) within :func:`~avgs.acoustics.line_of_sight.wall_radius`, wide enough for sparse
        points, its unit the count from which a training pair was behind a wall."""
        from avgs.acoustics.line_of_sight import MARGIN_M, RADIUS_M, fit_blocked_count, wall_radius
        from avgs.acoustics.rir_binauralizer import NEVER_BLOCKED

        b, scale = model.binauralizer, float(self.scene.frame.scale)
        radius, margin = wall_radius(model.points.X, RADIUS_M * scale), MARGIN_M * scale  # the model's units
        unit = fit_blocked_count(self._counts_on_paths(model, radius, margin), self._in_sight)
        with torch.no_grad():
            b.wall_radius.fill_(radius)
            b.wall_margin.fill_(margin)
            b.wall_unit.fill_(NEVER_BLOCKED if unit is None else unit)
        if self._log is not None:
            self._log.write({"stage": "walls", "event": "fit", "radius_m": radius / scale, "unit_points": unit})
