"""Operator tools that run against a real server: a local launcher and a load generator."""
