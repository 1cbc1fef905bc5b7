"""The jobs stage."""
