"""hlr-lab's file formats (docs/formats.md): versioned, validated on read, written atomically."""
