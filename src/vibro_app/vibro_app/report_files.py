"""The file names of the analysis report, apart from the plotting code (matplotlib), so that what an
output folder holds can be known without loading it."""

#: figure name -> file name, as :func:`vibro_app.report.write_figures` writes them
FIGURE_FILES = {"displacements": "displacements.png", "cor": "cor_per_impact.png",
                "friction": "friction_per_flight.png", "accelerometer_spectrum": "accel_spectrum.png",
                "histogram_qq": "cor_hist_qq.png", "simulated_vs_measured": "simulated_vs_measured.png"}
REPORT_HTML = "report.html"
