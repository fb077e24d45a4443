"""Applications: the sensor and the backend assembled from typed configurations, for the
command line and for Python alike."""
