"""The city-scale side of the link: a broker's certificates and ACLs, tile ownership of
backends, and the backend's signed assessments (see ``docs/fleet.md``)."""
