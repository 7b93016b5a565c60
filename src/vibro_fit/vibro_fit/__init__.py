"""Motion identification: structure sine fit, free-flight parabolas, impact times, per-impact COR, friction,
accelerometer impacts.

Entry points (plain Python, no rclpy):
- :func:`vibro_fit.identify.identify` (whole track -> :class:`~vibro_fit.identify.Identification`)
- :class:`vibro_fit.streaming.StreamingFitter` (frame by frame, one flight of latency; trajectory_fitter node)
- :class:`vibro_fit.accel_impacts.AccelImpactDetector` (accelerometer blocks -> impacts; impact_detector node)
- :func:`vibro_fit.results.results_document` (contract results.json sections)
- :mod:`vibro_app.report` (figures and the HTML report)
"""
