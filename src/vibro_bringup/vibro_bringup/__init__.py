"""Launch files, parameters, the node table (graph_spec) and the graph runner (graph_runner, supervisor)."""
