"""What the emulator runs for a rig (``stand emulate --rig``): the coupled plant, each channel's
plant as the emulator takes it, and the truth a run of an emulated rig can be compared with.

Each channel's emulated dynamometer measures over the channel's ``range_kgf`` (the rig file's
word for the transducer's range); a channel's plant file may leave its ``[sensor] range_kgf``
out or give the same value. The structure must be one a structure can give
(:func:`plant.rig.physical_check`): an emulator of a structure that cannot exist would teach
a controller a rig that no test will ever have.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from plant.config import PlantConfig
from plant.params import ModelError
from plant.rig import PhysicalCheck, RigModel, StructureChange, physical_check

from .config import ChannelConfig, RigConfig, RigError
from .structure import judge_structure


@dataclass(frozen=True)
class EmulatedRigPlant:
    """The rig's plant as the emulator runs it."""

    model: RigModel
    #: each channel's plant (in the rig's channel order), its sensor's range the channel's
    plants: list[PlantConfig] = field(repr=False)
    structure: PhysicalCheck = field(repr=False)

    @property
    def initial_forces_kgf(self) -> np.ndarray:
        return np.array([p.initial_force_kgf for p in self.plants])


def sensor_range_conflict(channel: ChannelConfig) -> str | None:
    """Why the channel's plant and the channel disagree on the dynamometer's range (None: they
    do not)."""
    if channel.plant is None or "range_kgf" not in channel.plant.sensor:
        return None
    given = float(channel.plant.sensor["range_kgf"])
    if math.isclose(given, channel.range_kgf, rel_tol=1e-12):
        return None
    return (f"channel {channel.name}: its plant's [sensor] range_kgf = {given:g} but the channel's "
            f"range_kgf = {channel.range_kgf:g}: the dynamometer has one range; leave it out of the "
            "plant (the channel's is used)")


def channel_plant(channel: ChannelConfig) -> PlantConfig:
    """The channel's plant with its dynamometer's range set to the channel's."""
    if channel.plant is None:
        raise RigError(f"channel {channel.name} has no plant: the emulator needs a "
                       "[channel.plant] table (or plant = \"FILE.toml\") for every channel")
    conflict = sensor_range_conflict(channel)
    if conflict:
        raise RigError(conflict)
    plant = replace(channel.plant, sensor={**channel.plant.sensor, "range_kgf": channel.range_kgf})
    try:
        return plant.validate()
    except ModelError as exc:
        raise RigError(f"channel {channel.name}: {exc}") from None


def emulated_plant(rig: RigConfig) -> EmulatedRigPlant:
    """The coupled plant of ``rig``; :class:`RigError` when it cannot be emulated (a channel
    without a plant, a range given twice differently, a structure no symmetric positive
    definite stiffness gives)."""
    plants = [channel_plant(c) for c in rig.channels]
    verdict = judge_structure(rig)
    if verdict.reason:
        raise RigError(f"{rig.where}: the structure (from {rig.structure_from}) cannot be "
                       f"emulated: {verdict.reason}")
    G = rig.G if rig.G is not None else np.diag([p.model.g for p in plants])
    check = verdict.check or physical_check(G)
    try:
        model = RigModel([p.model for p in plants], G, rig.names, rig.changes)
    except ModelError as exc:
        raise RigError(f"{rig.where}: {exc}") from None
    return EmulatedRigPlant(model, plants, check)


def channel_seed(seed: int | None, index: int) -> int | None:
    """The noise seed of channel ``index``'s dynamometer in a rig emulated with ``seed``: one
    independent stream per channel (None: unseeded)."""
    if seed is None:
        return None
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def rig_truth(rig: RigConfig, plant: EmulatedRigPlant | None = None) -> dict[str, Any]:
    """The emulated rig's truth, as a run's ``truth.json`` holds it (never read by the
    analysis): the structure G (kgf/(%·s), rows and columns in the channels' order; the intact
    one), where it came from, each channel's plant (:meth:`PlantConfig.to_dict`) by name, and
    the structure's scheduled changes (``changes``: channel, stiffness_factor, from_s, ramp_s,
    on the emulator's stand time) with ``G_changed``, G once every change is complete (G
    itself without changes)."""
    plant = plant or emulated_plant(rig)
    return {
        "rig": rig.name,
        "channels": rig.names,
        "G": plant.model.G.tolist(),
        "structure_from": rig.structure_from,
        "plants": {name: p.to_dict() for name, p in zip(rig.names, plant.plants)},
        "changes": [change_dict(rig, c) for c in rig.changes],
        "G_changed": plant.model.G_changed.tolist(),
    }


def change_dict(rig: RigConfig, change: StructureChange) -> dict[str, Any]:
    """A scheduled change as the truth and ``stand rig check --json`` give it."""
    return {"channel": rig.names[change.channel], "stiffness_factor": change.stiffness_factor,
            "from_s": change.from_s, "ramp_s": change.ramp_s}
