"""Hardware abstraction layer: devices behind small interfaces; nothing else touches hardware."""
