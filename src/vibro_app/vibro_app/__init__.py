"""The vibro command line and the offline pipeline: analyze, results.json, reports, campaigns."""
