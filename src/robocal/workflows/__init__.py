"""Workflows: a campaign directory in, result files out. Shared by the CLI and the pipeline stages."""
