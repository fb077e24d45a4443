"""rfsas-hw: RF situational awareness sensor toolkit.

The flow is one-way: sources → observations → df → bearings → privacy → link
→ backend. Each stage is a library class usable without the CLI.
"""

__version__ = "0.1.0"
