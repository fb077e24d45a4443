"""V2X: RF-SAS detections as ETSI Collective Perception Messages (CPM v2)."""
