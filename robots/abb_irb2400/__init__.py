"""ABB IRB 2400 robot plugin."""
