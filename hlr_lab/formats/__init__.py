"""hlr-lab's file formats (DESIGN §4): versioned, validated on read, written atomically."""
