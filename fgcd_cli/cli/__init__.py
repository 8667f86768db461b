"""Typer commands only: parse, call a use case, render with rich."""
