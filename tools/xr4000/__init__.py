"""The XR4000 base-controller emulator (the controller side of docs/design.md §12)."""
