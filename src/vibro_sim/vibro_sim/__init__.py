"""Vibro-impact models (COR and Hertz-damped contact), simulator node and a synthetic rig that writes recordings
with ground truth.

Core API (SI units, lab frame, positive up; no rclpy needed):

- :class:`~vibro_model.kinematics.StructureKinematics`, :class:`~vibro_sim.params.BallCavity`
- force laws (:mod:`vibro_sim.forces`): NoForce, Coulomb, Viscous, Quadratic, PerFlight
- COR laws (:mod:`vibro_sim.restitution`): Constant, PerPlate, VelocityDependent, PerImpact, Scattered
- :func:`~vibro_sim.cor_model.simulate_cor` -> :class:`~vibro_sim.cor_model.SimResult`
  (solver settings: :class:`~vibro_sim.cor_model.CorSolver`)
- :func:`~vibro_sim.hertz_model.simulate_hertz`, :func:`~vibro_sim.hertz_model.hertz_effective_cor`
  (model settings: :class:`~vibro_sim.hertz_model.HertzSolver`)
- :func:`~vibro_sim.deviation.deviation` (Eq. 18)
- :class:`~vibro_sim.replay.ReplayInputs`, :func:`~vibro_sim.replay.simulate_measured`
- synthetic rig: :mod:`vibro_sim.synth` (``synthesize(out_dir, SynthConfig(...))``)
"""
