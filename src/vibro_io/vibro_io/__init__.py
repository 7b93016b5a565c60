"""Recording I/O for vibro: rig.yaml validation, frame sequences, accelerometer CSV, DIC tracks and results files."""
