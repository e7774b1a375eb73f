"""Pictures of results (matplotlib only, headless): style (field titles, labels, colour
limits), figures, PNG/GIF/MP4, PDF report."""

from .deformed import fine_grid, on_fine_grid, rigid_motion, to_deformed
from .figures import displacement_figure, field_figure, plot_displacement, truth_at_nodes
from .media import export_gif, export_mp4, export_png
from .report import export_report, line_profile, report_page_count
from .sem import plot_scan_lines, scan_lines_figure
from .style import colour_limits, field_colour_limits, field_label, field_title

__all__ = [
    "displacement_figure", "plot_displacement", "truth_at_nodes", "field_figure",
    "field_label", "field_title", "colour_limits", "field_colour_limits",
    "export_png", "export_gif", "export_mp4",
    "export_report", "line_profile", "report_page_count", "to_deformed",
    "fine_grid", "on_fine_grid", "rigid_motion",
    "scan_lines_figure", "plot_scan_lines",
]
