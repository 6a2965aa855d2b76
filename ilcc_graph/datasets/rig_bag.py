"""A rig's topics in one ROS bag: moments paired by time (docs/rig.md, docs/datasets.md).

Every sensor has a topic (``sensors.<name>.topic``; without it, the bag's only topic of its type
when the rig has one sensor of that kind). One sensor is the anchor (``data.anchor``; default the
first LiDAR): each of its messages is a candidate moment, named by its bag time like the single-pair
bag source names frames (``t0012.345``). Every other sensor's message joins the anchor's when each is
the other's nearest in time and they are at most ``data.sync_tolerance`` apart (header stamps, or bag
times when the stamps are zero or do not pair, as the single-pair source decides). Moments are chosen
by the single-pair source's rule: one per still pause of a walk-and-pause recording, else every
candidate up to ``data.max_moments``. Motion is measured on every camera (else on the anchor): the
rig is still where no camera sees anything move (``timeline.common_still_runs``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ilcc_graph.config import RigConfig
from ilcc_graph.datasets.ros_messages import CLOUD, COMPRESSED, IMAGE
from ilcc_graph.datasets.rosbag import BagSource
from ilcc_graph.datasets.timeline import (
    IMAGE_STILL,
    LIDAR_STILL,
    Stream,
    common_still_runs,
    nearest,
    pair_by_time,
)
from ilcc_graph.errors import InputError, quote

__all__ = ["RigBag"]

log = logging.getLogger(__name__)


class RigBag(BagSource):
    """The bag of a rig, read with the single-pair bag source's readers (lazily, once per process)."""

    def __init__(self, rig: RigConfig) -> None:
        d, path = rig.data, rig.bag_path()
        if path is None:
            raise ValueError("RigBag: the rig has no data.bag")
        if not path.exists():
            raise InputError(f"{rig.source}: data.bag = {quote(d.bag)}: expected a ROS bag; {path} not found")
        super().__init__(path, sync_tolerance=d.sync_tolerance, min_pause=d.min_pause, select=d.select,
                         max_frames=d.max_moments)  # fmt: skip
        self.rig = rig
        self.sensor_topics: dict[str, str] = {}
        self._motion: list[str] = []

    def _sensor_topics(self) -> dict[str, str]:
        """sensor -> its topic; InputError naming the rig file's key and listing the bag's topics."""
        found = {n: info.msgtype for n, info in self._guard(lambda: self._reader().topics).items()}
        listing = ", ".join(f"{n} ({t})" for n, t in sorted(found.items())) or "none"
        given = {s.topic for s in self.rig.sensors if s.topic is not None}
        out = {}
        for s in self.rig.sensors:
            types = (CLOUD,) if s.kind == "lidar" else (IMAGE, COMPRESSED)
            key = f"{self.rig.source}: sensors.{s.name}.topic"
            if s.topic is not None:
                if found.get(s.topic) not in types:
                    what = "no such topic" if s.topic not in found else f"its type is {found[s.topic]}"
                    raise InputError(f"{key} = {quote(s.topic)}: {what} in {self.path}; topics: {listing}")
                out[s.name] = s.topic
                continue
            cands = sorted(n for n, t in found.items() if t in types and n not in given)
            if len(cands) != 1 or sum(x.kind == s.kind for x in self.rig.sensors) != 1:
                raise InputError(f"{key} = missing: expected one of the {' or '.join(types)} topics of "
                                 f"{self.path}; topics: {listing}")  # fmt: skip
            out[s.name] = cands[0]
        return out

    def _ring_model(self) -> Any:
        """The anchor LiDAR's beam table, to give rings to its clouds when they carry none (motion)."""
        s = self.rig.sensor(self.anchor())
        if s.lidar is None:
            raise InputError(
                f"{self.rig.source}: sensors.{s.name}.lidar.model = missing: expected a model to measure "
                f"motion on {self.sensor_topics[s.name]}, whose clouds have no ring field"
            )
        return s.lidar

    def anchor(self) -> str:
        rig = self.rig
        return rig.data.anchor or (rig.lidars[0] if rig.lidars else rig.names[0])

    def survey_rig(self) -> dict[str, Stream]:
        """Read the bag once: every sensor's stamps, and the motion seen by every camera (else the anchor)."""
        if self.streams:
            return self.streams
        self.sensor_topics = topics = self._sensor_topics()
        anchor = self.anchor()
        order = [anchor] + [n for n in self.rig.names if n != anchor]
        kinds = {s.name: s.kind for s in self.rig.sensors}
        streams = {
            topics[n]: Stream(topics[n], LIDAR_STILL if kinds[n] == "lidar" else IMAGE_STILL) for n in order
        }
        self._motion = [topics[n] for n in (self.rig.cameras or (anchor,))]
        self._record(streams, {topics[n] for n in self.rig.lidars}, set(self._motion), self._ring_model)
        if not streams[topics[anchor]].bag_ns:
            raise InputError(f"{self.path}: no message on {topics[anchor]} (sensor {anchor}, the anchor)")
        for n in order:
            if not streams[topics[n]].bag_ns:
                log.warning("%s: no message on %s: sensor %s is in no moment", self.path, topics[n], n)
        self._set_time_base(list(streams.values()), f"no {anchor} message has a partner")
        self._start_ns = int(self._guard(lambda: self._reader().start_time))
        self.streams = streams
        return streams

    def moments(self) -> tuple[list[Any], list[tuple[str, str]]]:
        """(moments, skipped): the chosen anchor messages with their partners (``rig.Moment``)."""
        from ilcc_graph.datasets.rig_source import Moment

        streams = self.survey_rig()
        anchor, topics = self.anchor(), self.sensor_topics
        ref = streams[topics[anchor]]
        ts = ref.times()
        others = [n for n in self.rig.names if n != anchor]
        times = {n: streams[topics[n]].times() for n in others}
        pairs = {n: pair_by_time(ts, times[n], self.tolerance) for n in others}
        paired = [i for i in range(len(ts)) if any(i in pairs[n] for n in others)]
        chosen, skipped = self._choose(ts, paired, times, pairs)
        moments = []
        for i in chosen:
            files: dict[str, Any] = {}
            missing: dict[str, str] = {}
            for n in self.rig.names:
                s = streams[topics[n]]
                if n == anchor:
                    files[n] = (s.topic, s.bag_ns[i])
                elif i in pairs[n]:
                    files[n] = (s.topic, s.bag_ns[pairs[n][i]])
                elif not len(times[n]):
                    missing[n] = f"no message on {s.topic} at all"
                else:
                    t = times[n]
                    gap = float(np.abs(t[nearest(t, ts[i : i + 1])] - ts[i])[0])
                    missing[n] = (
                        f"no message on {s.topic} within {self.tolerance} s (the nearest is {gap:.3f} s away)"
                    )
            moments.append(Moment(self._name(ref.bag_ns[i]), files, missing))
        log.info(
            "%s: %d %s messages, %d with a partner within %g s (%s time); %d moments",
            *(self.path, len(ts), anchor, len(paired), self.tolerance, ref.time_base, len(moments)),
        )
        return moments, skipped

    def _choose(
        self,
        ts: np.ndarray,
        paired: list[int],
        times: dict[str, np.ndarray],
        pairs: dict[str, dict[int, int]],
    ) -> tuple[list[int], list[tuple[str, str]]]:
        """Anchor indices chosen by the single-pair source's rule (docs/datasets.md), and skipped pauses."""
        runs, moving = common_still_runs([self.streams[t] for t in self._motion])
        pauses = [(a, b) for a, b in runs if b - a >= self.min_pause]
        if not (self.select == "pauses" or (self.select == "auto" and moving and pauses)):
            if len(paired) > self.max_frames:
                keep = sorted({round(x) for x in np.linspace(0, len(paired) - 1, self.max_frames)})
                paired = [paired[k] for k in keep]
            return paired, []
        chosen, skipped = [], []
        for a, b in pauses:
            inside = [i for i in paired if a <= ts[i] <= b
                      and all(a <= times[n][p[i]] <= b for n, p in pairs.items() if i in p)]  # fmt: skip
            if inside:
                chosen.append(min(inside, key=lambda i: abs(ts[i] - 0.5 * (a + b))))
            else:
                why = f"no moment with a partner within {self.tolerance} s in this still pause"
                skipped.append((f"pause-{self._name(a * 1e9)}", why))
        return chosen, skipped
