"""The online compensation service: bundles, the Newton engine, the JSON-lines TCP server and its client."""
