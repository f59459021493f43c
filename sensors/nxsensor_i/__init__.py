"""NextWare nxSensor-I laser line sensor plugin."""
