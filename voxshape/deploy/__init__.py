"""Deployment and security: who may do what on a secured session's bus (access.py) and the
development certificates and credentials (certs.py)."""
