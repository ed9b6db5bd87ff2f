"""The shipped tree library (manifest and recipes), installed as ``forest.library_files``.

Read through :func:`forest.library.open_library`; nothing here is imported for code.
"""
