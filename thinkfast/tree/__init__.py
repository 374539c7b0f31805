"""The action tree: its in-memory form and its HDF5 file (schema, provenance, fingerprint)."""
