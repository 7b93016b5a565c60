"""The exit codes of vibro's nodes (:func:`vibro_ros.node_support.run_node`), which the supervisors of the graph
judge alike (``vibro graph`` and ros2 launch: :mod:`vibro_bringup.exit_policy`). Plain module (no rclpy)."""

#: finished: the node's stream ended (or SIGINT/SIGTERM)
FINISHED_OK = 0
#: the node refused its input, its parameters or another run's messages (vibro_ros.guard): never restarted
REFUSED = 2
#: the node found its run incomplete (frame slots the graph never tracked,
#: :meth:`vibro_ros.fit_results.FinalFitResults.unanswered_frames`) and judged nothing: never restarted, the run ends
INCOMPLETE = 3
