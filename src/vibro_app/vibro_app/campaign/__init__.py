"""``vibro campaign``: every recording of a sweep analysed on a Dask cluster, and one campaign report.

- :mod:`.runs`: which recordings (a folder searched for rig.yaml, or a list file) and their run names.
- :mod:`.fingerprint`: what a run's outputs were made from (inputs' sizes and times, rig.yaml, vibro's code):
  a run whose fingerprint matches is not redone (resume).
- :mod:`.task`: the Dask task of one run: ``vibro analyze``'s core (:func:`vibro_app.analyze.analyze_recording`).
- :mod:`.summary`: one row per run from its results.json; runs that disagree with their excitation group.
- :mod:`.report`: campaign.json, campaign.csv, figures, report.html.
- :mod:`.engine`: all of it on a cluster (:func:`run_campaign`).

Plain Python: no rclpy anywhere on this path (a machine without ROS runs campaigns); nothing starts a
cluster at import time.
"""
