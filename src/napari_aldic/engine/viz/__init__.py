"""Pictures of results (matplotlib only, headless): figures, PNG/GIF/MP4, PDF report."""

from .figures import (colour_limits, displacement_figure, field_figure, field_label,
                      plot_displacement, truth_at_nodes)
from .media import export_gif, export_mp4, export_png
from .report import export_report, line_profile, report_page_count

__all__ = [
    "displacement_figure", "plot_displacement", "truth_at_nodes", "field_figure",
    "field_label", "colour_limits", "export_png", "export_gif", "export_mp4",
    "export_report", "line_profile", "report_page_count",
]
