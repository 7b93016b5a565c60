"""vibro's domain model, plain Python (no ROS): one place for what the other packages share.

- :mod:`vibro_model.constants`: physical constants (gravity), defined once.
- :mod:`vibro_model.units`: named unit conversions (mm <-> m, s <-> ms, N <-> mN).
- :mod:`vibro_model.results`: the results document of one recording as types, SI inside (m, m/s, s, N),
  each with ``to_dict()``/``from_dict()`` for the results.json keys of docs/recording-format.md.
- :mod:`vibro_model.kinematics`: the structure's prescribed motion Y_s(t) (``StructureKinematics``, SI), the one
  kinematic type the simulator, the fit results (``StructureMotion.kinematics()``) and the discrepancy analysis use.
- :mod:`vibro_model.codec`: the one results.json codec (schema, JSON-number sanitiser, writer, reader
  with validation).
"""
