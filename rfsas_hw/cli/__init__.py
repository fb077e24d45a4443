"""The ``rfsas`` command line: thin click shells over the library."""
