"""The file names of the analysis report, apart from the plotting code (matplotlib), so that what an
output folder holds can be known without loading it."""

from pathlib import Path

#: figure name -> file name, as :func:`vibro_app.report.write_figures` writes them
FIGURE_FILES = {"displacements": "displacements.png", "cor": "cor_per_impact.png",
                "friction": "friction_per_flight.png", "accelerometer_spectrum": "accel_spectrum.png",
                "histogram_qq": "cor_hist_qq.png", "simulated_vs_measured": "simulated_vs_measured.png"}
REPORT_HTML = "report.html"
#: the vector format every report figure is also saved in, beside its PNG
VECTOR_SUFFIX = ".svg"


def vector_twin(path: str | Path) -> Path:
    """The vector (SVG) file saved beside a report figure's PNG ``path``."""
    return Path(path).with_suffix(VECTOR_SUFFIX)


def with_vector_twins(names) -> tuple[str, ...]:
    """``names`` followed by the vector twin of each PNG among them (what a report may write)."""
    names = tuple(names)
    return names + tuple(vector_twin(n).name for n in names if str(n).lower().endswith(".png"))
