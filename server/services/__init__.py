"""The service layer between the routes and storage: one module per REST resource (assets,
scenes, materials, renders, publications, captures), with plain functions that take a database
session (and the settings, the blob store or the app state when they need them) and return
database rows or plain data, or raise the domain errors of errors.py.

They know nothing of HTTP: a route reads the request, calls them, and turns their result into
a response and their errors into status codes (server/routes/errors.py). Transactions belong to
the caller (a route commits, or opens ``s.begin()``), so that several calls can make one unit of
work, as a fit saved as a new material design does.
"""
