"""Simulation: seeded synthetic rigs with known truth, rendered frames, and prepared test scenes.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.sim.simulate` | rigs, wand paths and static objects with their truth (``wandcal simulate``, the demo) |
| :mod:`~wandcal.calib.sim.shapes` | rigs of the shapes real rigs have (ring, dome, two tiers, hallway; 8-256 cameras, sparse views; ``simulate --shape``) |
| :mod:`~wandcal.calib.sim.intrinsics` | given intrinsics a few per cent off the truth, as real ones are (``simulate --intrinsics-error``) |
| :mod:`~wandcal.calib.sim.render` | marker spots rendered as a camera records them |
| :mod:`~wandcal.calib.sim.scenes` | scenes taken part-way through the pipeline, for tests and benchmarks |
| :mod:`~wandcal.calib.sim.references` | world references besides the L-frame: floor points and a dropped ball (``simulate --floor``, ``--drop``) |
| :mod:`~wandcal.calib.sim.faults` | simulated captures with one thing wrong, the cases the judgement is tested on |
| :mod:`~wandcal.calib.sim.takes` | ordinary takes: markers on moving bodies, unlabelled blobs, a camera knocked or drifting (``simulate --take``) |
| :mod:`~wandcal.calib.sim.cavity` | particles in a water-filled cavity seen through a flat window, as OpenPTV's test cavity (the refraction matcher's truth) |
"""
