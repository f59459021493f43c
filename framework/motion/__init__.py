"""What moves a robot or plans its moves: station and kinematic planners, acquisition,
validation and scanning. Imports the layers below it (core, config, io, devices,
estimation); takes configuration sections, never the root configuration."""
