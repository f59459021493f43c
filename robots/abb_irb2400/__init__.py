"""ABB IRB 2400 robot plugin: kinematic model (Pinocchio), the spherecal line protocol,
a driver over a serial line or TCP, the RAPID server modules (with an offline syntax
check), pose streaming over Externally Guided Motion (EGM) and a simulated controller
with its EGM stream.

See docs/robot-abb-irb2400.md. The plugin entry point is :mod:`.plugin`.

The names below load on first use (PEP 562): registering the plugin (every ``solve``)
needs its configuration model, not its simulated controller.
"""

from __future__ import annotations

from spherecal.plugins import lazy_attributes


#: name -> the module that defines it
_WHERE = {
    "AbbIrb2400Config": ".config",
    "SimulatedControllerSettings": ".config",
    "WorkspaceBox": ".config",
    "EgmSettings": ".config",
    "SimulatedEgmSettings": ".config",
    "EgmReceiver": ".egm_receiver",
    "EgmSample": ".egm_messages",
    "decode_egm_robot": ".egm_messages",
    "encode_egm_robot": ".egm_messages",
    "ControllerMotionSource": ".egm_sim",
    "EgmFaults": ".egm_sim",
    "SimulatedEgmServer": ".egm_sim",
    "AbbIrb2400Robot": ".driver",
    "Irb2400Geometry": ".kinematics",
    "Irb2400Kinematics": ".kinematics",
    "JointLimitError": ".kinematics",
    "UnreachableError": ".kinematics",
    "flange_pose_from_joints": ".kinematics",
    "Faults": ".simulator",
    "SimulatedIrb2400": ".simulator",
    "SimulatorServer": ".simulator",
    "start_simulator": ".simulator",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_attributes(__name__, _WHERE)
