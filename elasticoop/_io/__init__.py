"""Results as files and text: xarray/netCDF, CSV, JSON summaries."""
