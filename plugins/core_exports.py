"""The built-in plugin ``core_exports``: registers the core's brand-free exporters (4x4
matrices, xyz + quaternion, ROS 2; :data:`spherecal.report.export.CORE_EXPORTERS`),
found through its entry point as any plugin is."""

from __future__ import annotations

from spherecal.report.export import CORE_EXPORTERS

from spherecal.plugins.markers import hookimpl


@hookimpl
def spherecal_register_exporters(registry) -> None:
    """Register :data:`~spherecal.report.export.CORE_EXPORTERS`."""
    for exporter in CORE_EXPORTERS:
        registry.add_exporter(exporter)
