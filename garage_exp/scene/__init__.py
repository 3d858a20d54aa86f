"""Backend-neutral scene description and the builder that makes it from a plan and factors."""
