"""A rig of N like channels along a chain: for benchmarks and for trying a rig's size.

Every channel is a copy of one template channel (its range, force limit and emulated plant),
the channels spread evenly over M buses in blocks (neighbours share a bus where they can), node ids
1, 2 / 3, 4 / ... on each bus. The structure is a chain: a stiffness of 10 kgf/mm at every
attachment point and ``coupling``·10 between neighbours (``K`` tridiagonal, positive definite
for ``coupling`` < 0.5), every actuator the template's flow gain ``c/A = g/10``, so
``G = K·diag(c/A)`` has the template's g on the diagonal and ``coupling``·g beside it::

    from rig.chain import chain_rig
    from rig.config import load_rig_file
    rig16 = chain_rig(load_rig_file("examples/rig.toml").channels[0], 16, 4)
"""
from __future__ import annotations

import dataclasses

import numpy as np

from plant.config import PlantConfig

from .config import BusConfig, ChannelConfig, RigConfig, RigError

#: the stiffness at each attachment point, kgf/mm (only the ratios matter for G)
POINT_STIFFNESS = 10.0


def chain_rig(template: ChannelConfig, channels: int, buses: int, coupling: float = 0.3,
              period_s: float = 0.002, tag: str = "chain", name: str | None = None,
              data_bitrate: int | None = None) -> RigConfig:
    """``channels`` copies of ``template`` on ``buses`` loopback buses (``udp_loopback:{tag}-canK``),
    neighbours coupled ``coupling`` through a chain stiffness (module docstring); with
    ``data_bitrate`` CAN FD buses (1 Mbit/s nominal, the data phase at that rate)."""
    if template.plant is None:
        raise RigError(f"channel {template.name!r} has no plant to copy: a chain rig's channels "
                       "are emulated copies of it")
    if not (channels >= 1 and 1 <= buses <= channels):
        raise RigError(f"a chain rig needs at least one channel and 1 to {channels} buses, "
                       f"not {channels} channel(s) on {buses} bus(es)")
    if not 0.0 <= coupling < 0.5:
        raise RigError(f"coupling {coupling:g}: give 0 to below 0.5 (a chain's stiffness is "
                       "positive definite only then)")
    per_bus = -(-channels // buses)     # the most on one bus: the buses share them evenly
    if 2 * per_bus > 127:
        raise RigError(f"{per_bus} channels on one bus need {2 * per_bus} node ids; CANopen has 127")
    g = float(template.plant.model.g)
    flow = g / POINT_STIFFNESS
    K = POINT_STIFFNESS * (np.eye(channels) + coupling * (np.eye(channels, k=1) + np.eye(channels, k=-1)))
    fd = data_bitrate is not None
    bus_list = [BusConfig(f"can{b}", f"udp_loopback:{tag}-can{b}", fd=fd, data_bitrate=data_bitrate)
                for b in range(buses)]
    width = len(str(channels))
    chans = []
    for i in range(channels):
        b = i * buses // channels
        k = i - -(-b * channels // buses)    # the channel's place on its bus
        plant = PlantConfig(model=template.plant.model.with_params({"g": g}),
                            sensor=dict(template.plant.sensor),
                            initial_force_kgf=template.plant.initial_force_kgf)
        chans.append(dataclasses.replace(template, name=f"ch{i + 1:0{width}d}", bus=f"can{b}",
                                         valve_id=2 * k + 1, dynamometer_id=2 * k + 2,
                                         plant=plant, plant_g=None))
    kind = f" CAN FD {data_bitrate / 1e6:g} Mbit/s" if fd else ""
    return RigConfig(name=name or f"chain of {channels} on {buses}{kind} bus(es), neighbours {coupling:.0%}",
                     buses=bus_list, channels=chans, G=K * flow, structure_from="K", K=K,
                     period_s=period_s)
