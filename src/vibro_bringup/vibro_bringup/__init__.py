"""Launch files, parameters, the node-graph runner and the vibro command-line interface."""
