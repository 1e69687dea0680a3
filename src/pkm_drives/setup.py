from setuptools import setup

package_name = 'pkm_drives'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['eds/*.eds']},
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Servo drives: the CiA 402 drive profile, a CANopen transport, virtual '
        'CiA 402 drives, homing, and the drive interface node.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'drives_node = pkm_drives.drives_node:main',
            'virtual_drives_node = pkm_drives.virtual_drives_node:main',
            'ros2_control_node = pkm_drives.ros2_control_node:main',
            'ros2_control_sim_node = pkm_drives.ros2_control_sim_node:main',
        ],
    },
)
