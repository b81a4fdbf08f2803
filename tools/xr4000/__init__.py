"""The XR4000 base-controller emulator (the controller side of SPEC §12)."""
