"""The configuration: the model (model.py), its cross-key checks, loading, secrets, the TOML writer, TLS, and the core's parameters built from it (params.py)."""
