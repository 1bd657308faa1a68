"""The one typed error the extension raises for problems the user can fix in the scene (not a bug).

Here rather than in bridge/ because the bone mapping (bone_mapping/, no bpy) raises it too."""


class AdjustError(Exception):
    """A user-facing problem with the scene or the settings (not a bug).

    str(error) is a single line, ready for an operator's ``self.report({'ERROR'}, str(error))``.
    Raised before anything is changed, so catching it leaves the file as it was.
    """

    def __init__(self, message):
        # Reports and the CLI print one line: fold any line breaks a caller let slip in.
        super().__init__(" ".join(str(message).split()))
