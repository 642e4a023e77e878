"""Typed scenario configs (YAML) and the builder that turns them into diagrams."""
