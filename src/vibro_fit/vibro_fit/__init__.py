"""Motion identification: structure sine fit, free-flight parabolas, impact times, per-impact COR, friction, accelerometer impacts."""
