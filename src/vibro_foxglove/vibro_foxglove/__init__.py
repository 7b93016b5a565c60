"""The Foxglove bridge node: a vibro graph watched live in Foxglove."""
