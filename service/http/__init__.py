"""The HTTP edge: ASGI middlewares (limits, API key, request context), admission control,
validation messages, exception handlers and the served OpenAPI document.
"""
