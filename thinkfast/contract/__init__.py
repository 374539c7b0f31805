"""What other programs depend on, in one place each: key names, the detection message, frames,
the EGM codec, zenoh sessions and the flight-record schema (docs/INTERFACES.md)."""
